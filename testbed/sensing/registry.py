"""The sensors by name: the built-ins (:data:`SENSORS`, one line each) and the installed plug-ins (entry point group
``roadtrack.sensors``: a :class:`~testbed.sensing.sensor.Sensor`, or a function of no argument returning one).

A scenario's sensors are the LiDAR and the names of ``sensor.extra`` (:func:`scenario_sensors`); a plug-in whose
name is invalid or taken, or whose streams another sensor uses, is skipped with one PluginWarning line.
"""
from __future__ import annotations

import functools
import warnings

from ..common import streams
from ..config import ConfigError
from ..scenario.spec import Scenario
from .lidar import LIDAR
from .radar import RADAR
from .sensor import Sensor

SENSORS: dict[str, Sensor] = {
    "lidar": LIDAR,
    "radar": RADAR,
}
"""The built-in sensors by name (add a sensor: its module and one line here)."""

SENSOR_GROUP = "roadtrack.sensors"
"""Entry-point group of plug-in sensors."""


def _plugin(ep, taken: dict[str, Sensor]) -> Sensor:
    """The Sensor of entry point ``ep``; ValueError/TypeError (one line) when it cannot join ``taken``."""
    from roadtrack.trackers.plugins import NAME  # not at import: importing trackers loads its plug-ins, whose warnings the
    # CLI shows as one line only once its commands run (testbed/cli/main.py)

    if not NAME.match(ep.name):
        raise ValueError("its name must be lower-case letters and digits joined by single hyphens")
    if ep.name in taken:
        raise ValueError(f"{ep.name!r} is already a sensor")
    obj = ep.load()
    if not isinstance(obj, Sensor) and callable(obj):
        obj = obj()
    if not isinstance(obj, Sensor) or obj.name != ep.name:
        raise TypeError(f"gives {obj!r:.60}, not a testbed.sensing.Sensor named {ep.name!r}")
    used = {s: n for n, other in taken.items() for s in other.streams}
    for s in obj.streams:
        if s in used or s in streams.LEGACY:
            raise ValueError(f"its random stream {s!r} belongs to {used.get(s, 'the testbed')!r}")
    streams.check_distinct([*used, *obj.streams])
    return obj


@functools.lru_cache(maxsize=1)
def sensor_registry() -> dict[str, Sensor]:
    """Built-in and installed sensors by name (read once per process; ``sensor_registry.cache_clear()`` re-reads
    the installed ones). Do not modify the dict."""
    from roadtrack.trackers.plugins import PluginWarning, entry_points, origin  # see _plugin

    out = dict(SENSORS)
    for ep in entry_points(SENSOR_GROUP):
        try:
            out[ep.name] = _plugin(ep, out)
        except Exception as err:  # noqa: BLE001 - a broken plug-in is skipped, never fatal
            why = f"{type(err).__name__}: {str(err).splitlines()[0] if str(err) else ''}".rstrip(": ")
            warnings.warn(f"plug-in skipped: {origin(ep)}: {why}", PluginWarning, stacklevel=2)
    return out


def scenario_sensors(scn: Scenario) -> list[Sensor]:
    """The sensors ``scn`` senses with: the LiDAR, then ``sensor.extra`` in its order; ConfigError (one line naming
    ``sensor.extra[i]`` and the valid names) for an unknown or repeated name."""
    known = sensor_registry()
    out = [LIDAR]
    for i, name in enumerate(scn.sensor.extra):
        if name not in known or name == LIDAR.name or known[name] in out:
            others = ", ".join(sorted(n for n in known if n != LIDAR.name)) or "none installed"
            why = "is always on" if name == LIDAR.name else ("is listed twice" if name in known else "is not a sensor")
            raise ConfigError(f"sensor.extra[{i}]", f"{name!r} {why}; allowed: {others}")
        out.append(known[name])
    return out
