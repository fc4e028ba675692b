"""Whole trackers by name, beside the built-in combinations: Stone Soup's (optional extra) and those of installed
plug-in packages (entry point group ``roadtrack.trackers``: a class or function of the scenario returning an
object with ``step(frame)``, like ``--tracker module:Class``). ``testbed trackers`` lists them, ``testbed run
--tracker NAME`` and ``testbed.run(scn, tracker=NAME)`` run them."""
from __future__ import annotations

import functools
import warnings
from dataclasses import dataclass
from typing import Any

from roadtrack.trackers.plugins import NAME, TRACKER_GROUP, PluginWarning, entry_points, origin

from ..config import ConfigError
from ..common.usercode import load_object


@dataclass(frozen=True)
class NamedTracker:
    """A tracker known by name: ``factory`` is ``module:attr`` (a class or function of the scenario);
    ``doc`` one line; ``source`` where it comes from ("stonesoup" extra or the plug-in's package)."""

    name: str
    factory: str
    doc: str
    source: str


STONESOUP = {
    "stonesoup-gnn-kf": NamedTracker("stonesoup-gnn-kf", "roadtrack.testbed.tracking.stonesoup:gnn_kf",
                                     "Stone Soup 1.9: GNN (2-D assignment) of Kalman filters, Mahalanobis gate",
                                     "roadtrack[stonesoup]"),
    "stonesoup-jpda-kf": NamedTracker("stonesoup-jpda-kf", "roadtrack.testbed.tracking.stonesoup:jpda_kf",
                                      "Stone Soup 1.9: JPDA (exact by EHM2; LBP for a cluster over budget) of Kalman filters",
                                      "roadtrack[stonesoup]"),
}


def _first_line(obj: Any) -> str:
    doc = (getattr(obj, "__doc__", None) or "").strip()
    return doc.splitlines()[0] if doc else ""


@functools.lru_cache(maxsize=1)
def named_trackers() -> dict[str, NamedTracker]:
    """The Stone Soup trackers and the installed ``roadtrack.trackers`` plug-ins, by name (read once per process;
    do not modify the dict). A plug-in whose name is invalid, taken (a Stone Soup tracker's or a built-in
    combination's) or that cannot be imported is skipped with one PluginWarning."""
    from roadtrack.trackers import parse_tracker_name

    out = dict(STONESOUP)
    for ep in entry_points(TRACKER_GROUP):
        why = None
        if not NAME.match(ep.name):
            why = "its name must be lower-case letters and digits joined by single hyphens"
        elif ep.name in out:
            why = f"{ep.name!r} is already a tracker"
        else:
            try:
                parse_tracker_name(ep.name)
                why = f"{ep.name!r} is a built-in combination"
            except ValueError:
                try:
                    doc = _first_line(ep.load())
                except Exception as err:  # noqa: BLE001 - a broken plug-in is skipped, never fatal
                    why = f"{type(err).__name__}: {str(err).splitlines()[0] if str(err) else ''}".rstrip(": ")
                else:
                    dist = getattr(ep, "dist", None)
                    out[ep.name] = NamedTracker(ep.name, ep.value, doc, dist.name if dist is not None else "?")
                    continue
        warnings.warn(f"plug-in skipped: {origin(ep)}: {why}", PluginWarning, stacklevel=2)
    return out


def is_named(name: Any) -> bool:
    """Whether ``name`` is a Stone Soup or plug-in tracker (not a built-in combination)."""
    return isinstance(name, str) and (name in STONESOUP or name in named_trackers())


def unknown_tracker(name: str) -> str:
    """The one-line message for a tracker name that is neither a combination nor a named tracker."""
    return (f"unknown tracker {name!r}: a combination [<wrapper>-]<associator>-<filter> (e.g. jpda-kf), a named "
            f"tracker ({', '.join(named_trackers())}) or module:Class; see `testbed trackers`")


def named_factory(name: str) -> Any:
    """The factory of the named tracker ``name`` (imported now: a missing Stone Soup is a one-line
    ConfigError saying which extra to install)."""
    known = named_trackers()
    if name not in known:
        raise ConfigError("--tracker", unknown_tracker(name))
    return load_object(known[name].factory, "--tracker", "Class")
