"""Checks of a scenario's ``[env.config]`` before highway-env sees it: data only, finite and bounded.

A scenario file is data that people share (README, "What a scenario file can do"). highway-env imports the
class named by ``other_vehicles_type`` (``highway_env.utils.class_from_path``), so any string that names a
class must be one of highway-env's own vehicle classes (:func:`vehicle_classes`); nothing else is ever
imported. Every number must be finite, of the kind the env's default has (a number where the default is a
number, a list where it is a list, ...), within :data:`GENERIC_MAX` in magnitude, and the keys that size the
work of a run (lanes, vehicles, durations, densities, road lengths, observation grids and images) within the
bounds of :data:`BOUNDS`, so ``testbed check`` answers at once and accepts exactly what ``run`` can run.
docs/limits.md explains each bound.
"""
from __future__ import annotations

import math
import re
from typing import Any

from ..config import ConfigError
from ..config.limits import check, limit

GENERIC_MAX = 1e6
"""Largest magnitude of any other number in ``[env.config]`` (highway-env's defaults are all below 1000)."""

LANES_MAX = 8  # as road.lanes: highway-env builds and steps every lane; 1e9 lanes take minutes to build
PIXELS_MAX = 4096 * 4096  # a rendered observation image (GrayscaleObservation)
GRID_CELLS_MAX = 1_000_000  # cells of an occupancy grid, filled for every vehicle on every step
SCREEN_MAX = 8192  # screen_width / screen_height [px] (the viewer's surface when an observation renders)

# key -> (least, largest or the name of a resource limit, what it is). A key matches at any depth
# (``observation.vehicles_count`` too).
BOUNDS: dict[str, tuple[float, float | str, str]] = {
    "lanes_count": (1, LANES_MAX, "lanes"),
    "no_lanes": (1, LANES_MAX, "lanes"),
    "roundabout_lanes": (1, LANES_MAX, "lanes"),
    "vehicles_count": (0, "vehicles", "vehicles"),
    "initial_vehicle_count": (0, "vehicles", "vehicles"),
    "other_vehicles": (0, "vehicles", "vehicles"),
    "controlled_vehicles": (1, 16, "controlled vehicles"),
    "duration": (0, "duration_s", "s"),
    "vehicles_density": (0, 100, "relative density"),
    "spawn_probability": (0, 1, "probability"),
    "ego_spacing": (0, 100, "relative spacing"),
    "length": (0, "road_length_m", "m"),
    "roundabout_radius": (1, "road_length_m", "m"),
    "scaling": (1e-3, 1e3, "pixels per m"),
    "screen_width": (1, SCREEN_MAX, "px"),
    "screen_height": (1, SCREEN_MAX, "px"),
    "stack_size": (1, 16, "frames"),
    "cells": (1, 3600, "lidar cells"),
    "horizon": (0, 100, "s"),
    "maximum_range": (0, "lidar_range_m", "m"),
}
INTEGER_KEYS = frozenset(("lanes_count", "no_lanes", "roundabout_lanes", "vehicles_count", "initial_vehicle_count",
                          "other_vehicles", "controlled_vehicles", "screen_width", "screen_height", "stack_size",
                          "cells"))  # highway-env uses them in range(); 2.5 lanes is a crash at reset
_SUFFIX_BOUNDS = {"_length": (0, "road_length_m", "m")}  # before_merge_length, converge_merge_length, ...
_CLASS_PATH = re.compile(r"^[A-Za-z_]\w*(\.[A-Za-z_]\w*)+$")


def vehicle_classes() -> dict[str, type]:
    """highway-env's own vehicle classes by their class path (``highway_env.vehicle.behavior.IDMVehicle``):
    the only classes a scenario file may name."""
    from highway_env.vehicle.kinematics import Vehicle

    out: dict[str, type] = {}
    todo = [Vehicle]
    while todo:
        cls = todo.pop()
        if cls.__module__.startswith("highway_env.") and "." not in cls.__qualname__:
            out[f"{cls.__module__}.{cls.__qualname__}"] = cls
        todo.extend(cls.__subclasses__())
    return dict(sorted(out.items()))


def check_env_config(config: dict, defaults: dict, path: str = "config") -> None:
    """ConfigError (one line, dotted key under ``path``) for anything in ``config`` that is not plain, finite,
    bounded data of the kind of ``defaults`` (the env's default config)."""
    for key, value in config.items():
        where = f"{path}.{key}"
        default = defaults.get(key) if isinstance(defaults, dict) else None
        if isinstance(value, dict):
            check_env_config(value, default if isinstance(default, dict) else {}, where)
            continue
        _check_kind(value, default, where)
        _check_value(key, value, where)
    _check_grid(config, path)


def _kind(value: Any) -> str:
    if isinstance(value, bool):
        return "true or false"
    if isinstance(value, (int, float)):
        return "a number"
    if isinstance(value, str):
        return "a string"
    if isinstance(value, (list, tuple)):
        return "a list"
    if isinstance(value, dict):
        return "a table"
    return type(value).__name__


def _check_kind(value: Any, default: Any, where: str) -> None:
    """The value must be of the default's kind (a default of None takes a number, a string or a list)."""
    if default is None or hasattr(default, "dtype"):  # numpy scalars in defaults: numbers
        want = "a number" if hasattr(default, "dtype") else None
    else:
        want = _kind(default)
    got = _kind(value)
    if want is not None and got != want:
        raise ConfigError(where, f"expected {want} (as the env's default {default!r}), got {value!r}")


def _numbers(value: Any) -> list[float]:
    if isinstance(value, bool):
        return []
    if isinstance(value, (int, float)):
        return [value]
    if isinstance(value, (list, tuple)):
        return [x for v in value for x in _numbers(v)]
    return []


def _strings(value: Any) -> list[str]:
    if isinstance(value, str):
        return [value]
    if isinstance(value, (list, tuple)):
        return [x for v in value for x in _strings(v)]
    return []


def _check_value(key: str, value: Any, where: str) -> None:
    for number in _numbers(value):
        try:
            finite = math.isfinite(number)
        except OverflowError:  # an integer beyond float64
            finite = False
        if not finite:
            raise ConfigError(where, f"expected a finite number, got {number!r}")
        if key in INTEGER_KEYS and not isinstance(number, int):
            raise ConfigError(where, f"expected an integer, got {number!r}")
        bounds = BOUNDS.get(key) or next((b for s, b in _SUFFIX_BOUNDS.items() if key.endswith(s)), None)
        if bounds is not None:
            _check_bounds(number, bounds, where)
        elif abs(number) > GENERIC_MAX:
            raise ConfigError(where, f"{number!r} is not allowed; numbers in env.config must be within "
                                     f"+-{GENERIC_MAX:g}")
    for text in _strings(value):
        if key == "other_vehicles_type" or _CLASS_PATH.match(text):
            _check_class_path(text, where)


def _check_bounds(number: float, bounds: tuple[float, float | str, str], where: str) -> None:
    low, high, unit = bounds
    if isinstance(high, str):  # a resource limit, raised with ROADTRACK_MAX_<NAME>
        if number < low:
            raise ConfigError(where, f"{number!r} is not allowed; must be >= {low:g} {unit}")
        check(high, number, where)
        return
    if not low <= number <= high:
        raise ConfigError(where, f"{number!r} is not allowed; must be in {low:g}..{high:g} {unit}")


def _check_class_path(text: str, where: str) -> None:
    allowed = vehicle_classes()
    if text not in allowed:
        shown = ", ".join(p.removeprefix("highway_env.vehicle.") for p in allowed)
        raise ConfigError(where, f"{text!r} is not one of highway-env's vehicle classes (a scenario file names no "
                                 f"other code); allowed: highway_env.vehicle.{{{shown}}}")


def _check_grid(config: dict, path: str) -> None:
    """Occupancy-grid cells ``prod((max - min) / step)`` and image pixels ``prod(observation_shape)``."""
    size, step = config.get("grid_size"), config.get("grid_step")
    if size is not None or step is not None:
        try:
            sides = [(float(hi) - float(lo)) / float(st) for (lo, hi), st in zip(size or [[-27.5, 27.5]] * 2,
                                                                                   step or [5.0, 5.0])]
        except (TypeError, ValueError, ZeroDivisionError):
            raise ConfigError(f"{path}.grid_step", "expected grid_size [[min_x, max_x], [min_y, max_y]] [m] and "
                                                   "grid_step [step_x, step_y] > 0 [m]") from None
        if any(not s > 0 for s in sides) or math.prod(sides) > GRID_CELLS_MAX:
            raise ConfigError(f"{path}.grid_step", f"the grid has {math.prod(sides):.3g} cells; allowed: 1.."
                                                   f"{GRID_CELLS_MAX} (max > min and a larger step)")
    shape = config.get("observation_shape")
    if isinstance(shape, (list, tuple)) and _numbers(shape):
        pixels = math.prod(_numbers(shape))
        if not 1 <= pixels <= PIXELS_MAX or min(_numbers(shape)) < 1:
            raise ConfigError(f"{path}.observation_shape", f"{pixels:.3g} pixels; allowed: 1..{PIXELS_MAX}")


def bounds_markdown() -> str:
    """The bounded ``[env.config]`` keys as a markdown table, for docs/limits.md."""
    rows = ["| key | allowed | unit |", "|---|---|---|"]
    for key, (low, high, unit) in {**BOUNDS, "*_length": _SUFFIX_BOUNDS["_length"]}.items():
        top = f"{limit(high):g} (limit `{high}`)" if isinstance(high, str) else f"{high:g}"
        rows.append(f"| `{key}` | {low:g} .. {top} | {unit} |")
    return "\n".join(rows) + "\n"
