"""Tracking stage: the tracker protocol (what a tracker is fed per scan and returns), the adapter of the built-in
trackers, named trackers (Stone Soup's, installed plug-ins'), loading a user's tracker from ``module:Class``."""
from .protocol import Frame, TrackSet, Tracker
from .builtin import BuiltinTracker
from .registry import NamedTracker, is_named, named_trackers
from .user import build_tracker, is_factory_spec, load_tracker, tracker_label

__all__ = ["BuiltinTracker", "Frame", "NamedTracker", "TrackSet", "Tracker", "build_tracker", "is_factory_spec",
           "is_named", "load_tracker", "named_trackers", "tracker_label"]
