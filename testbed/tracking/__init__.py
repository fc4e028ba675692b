"""Tracking stage: the tracker protocol (what a tracker is fed per scan and returns), the adapter of the built-in
trackers, loading a user's tracker from ``module:Class``, and the loop ``track(frames, tracker)``."""
from .protocol import Frame, TrackSet, Tracker
from .builtin import BuiltinTracker
from .user import build_tracker, load_tracker, tracker_label

__all__ = ["BuiltinTracker", "Frame", "TrackSet", "Tracker", "build_tracker", "load_tracker", "tracker_label"]
