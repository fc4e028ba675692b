"""Trackers by name: a built-in combination (``jpda-kf``, ``imm-pda-kf``, ...), a named tracker (Stone Soup's,
an installed plug-in's: testbed.tracking.registry) or a user's class named on the command line (``--tracker
my_module:MyTracker`` or ``--tracker path/to/file.py:MyTracker``)."""
from __future__ import annotations

import inspect
from typing import Any

from ..config import ConfigError
from ..common.usercode import is_code_spec, load_object
from .builtin import BuiltinTracker
from .protocol import Tracker
from .registry import is_named, named_factory


def is_factory_spec(spec: Any) -> bool:
    """Whether ``spec`` names a tracker factory (``module:Name``, ``file.py:Name`` or a named tracker) rather
    than a built-in combination."""
    return isinstance(spec, str) and (is_code_spec(spec) or is_named(spec))


def load_tracker(spec: str) -> Any:
    """The tracker factory named by ``spec`` (``module:Name``, ``file.py:Name`` or a named tracker such as
    ``stonesoup-jpda-kf``): a class or function called with the scenario (or with nothing when it takes no
    argument) to give a fresh tracker per run."""
    obj = named_factory(spec) if is_named(spec) else load_object(spec, "--tracker", "Class")
    if not callable(obj):
        raise ConfigError("--tracker", f"{spec!r} is not a class or function")
    return obj


def build_tracker(scenario, tracker: Any = None) -> Tracker:
    """A fresh protocol tracker for one run of ``scenario``. ``tracker``: None (the scenario's tracker), a
    built-in name (``jpda-kf``), a named tracker (``stonesoup-jpda-kf``), ``module:Name`` / ``file.py:Name``
    (:func:`load_tracker`), a factory (class or
    function of the scenario), or an object with ``step`` already built. ConfigError (one line) when it is none
    of these or the factory does not give an object with ``step``."""
    if tracker is None or (isinstance(tracker, str) and not is_factory_spec(tracker)):
        check_tracker_sensors(scenario)
        return BuiltinTracker(scenario.tracker.build(tracker or scenario.tracker.name), scenario.tracker.stitch_s,
                              scenario.tracker.sensors, scenario.tracker.box)
    if scenario.tracker.box and not isinstance(tracker, BuiltinTracker):  # never silently left out
        raise ConfigError("tracker.box", "box tracking is a step of the built-in trackers, not of a named or a "
                          "user's tracker: set it to false for this one")
    if tuple(scenario.tracker.sensors) != ("lidar",) and not isinstance(tracker, BuiltinTracker):  # never left out
        raise ConfigError("tracker.sensors", "the sensors a tracker takes are a setting of the built-in trackers; a "
                          "named or a user's tracker gets the LiDAR's detections: leave it at [\"lidar\"]")
    if scenario.tracker.stitch_s > 0 and not isinstance(tracker, BuiltinTracker):  # never silently left out
        raise ConfigError("tracker.stitch_s", "stitching is a step of the built-in trackers, not of a named or a "
                          "user's tracker: set it to 0 for this one")
    factory = load_tracker(tracker) if isinstance(tracker, str) else tracker
    if isinstance(factory, Tracker) and not inspect.isclass(factory):
        return factory
    if not callable(factory):
        raise ConfigError("tracker", f"expected a name, module:Name, a class or an object with step(), got "
                          f"{type(factory).__name__}")
    try:
        takes_scenario = bool(inspect.signature(factory).parameters)
    except (TypeError, ValueError):  # a builtin without a signature
        takes_scenario = True
    built = factory(scenario) if takes_scenario else factory()
    if not isinstance(built, Tracker):
        raise ConfigError("tracker", f"{getattr(factory, '__name__', factory)!r} gave a {type(built).__name__}, "
                          f"which has no step(frame) method")
    return built


def check_tracker_sensors(scenario) -> None:
    """ConfigError (one line naming ``tracker.sensors[i]``) unless every name is the LiDAR or a sensor of
    ``sensor.extra`` whose data a tracker can take (a ``measurements`` hook)."""
    from ..sensing.registry import scenario_sensors

    known = {s.name: s for s in scenario_sensors(scenario)}
    for i, name in enumerate(scenario.tracker.sensors):
        if name not in known:
            raise ConfigError(f"tracker.sensors[{i}]", f"{name!r} is not a sensor of this scenario; allowed: "
                              f"{', '.join(known)} (add further sensors to sensor.extra)")
        if name != "lidar" and known[name].measurements is None:
            raise ConfigError(f"tracker.sensors[{i}]", f"sensor {name!r} gives no measurements a tracker can take")
    if scenario.tracker.box and scenario.tracker.sensors[0] != "lidar":
        raise ConfigError("tracker.box", "box tracking reads the LiDAR's fitted boxes: tracker.sensors must start "
                          "with \"lidar\"")


def tracker_label(tracker: Any, scenario) -> str:
    """The name a run's outputs give its tracker: the built-in name, the ``module:Name`` typed, or the class."""
    if tracker is None:
        return scenario.tracker.name
    if isinstance(tracker, str):
        return tracker
    return getattr(tracker, "name", None) or getattr(tracker, "__name__", None) or type(tracker).__name__
