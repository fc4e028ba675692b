"""What a sensor of the sensing loop is: a :class:`Sensor` value (one module defines it, one line registers it:
testbed/sensing/registry.py ``SENSORS``, or an entry point ``roadtrack.sensors`` of an installed package).

Per run the loop builds a :class:`SensingContext`; per frame it calls, for each sensor,

    data = sensor.sense(ctx, truth, rngs)           what it senses of the truth frame; rngs: {stream name: Generator}
                                                    holding only the streams it names (``sensor.streams``)
    n_hits, in_view = sensor.visibility(ctx, truth, data)   per vehicle of truth (K,): int64 returns on it, bool
                                                    whether it lies in the sensor's field of view
    pd = sensor.pd(ctx)(data) if sensor.pd else None        pd(xy (T, 2) m, nominal, trucks=None) -> (T,) P_D
    meas = sensor.measurements(ctx, truth, data)            Measurements: what a tracker takes (optional hook;
                                                            ``tracker.sensors`` names the sensors a tracker uses)

``truth`` is a testbed.world.simulation.TruthFrame (ids (K,), xy (K, 2) m, velocity (K, 2) m/s, heading (K,) rad,
size (K, 3) m, ego_pose (3,); row 0 the ego car). Each sensor draws only from its own random streams
(testbed/common/streams.py): a new sensor named ``x`` gets ``sensor.x``, derived from the seed by its name, so
adding it changes no other stream. Visibility and P_D must be functions of (ctx, truth, data) only, so frames
read from the sensing cache (which stores ``data``) give them again.

The sensing cache stores a sensor's data when it is a :data:`table <table_problem>`: a dict of column name ->
numeric NumPy array (bool, int or float), all with the same first dimension (one row per detection; the trailing
shape fixed per column). Any other data is refused by the cache in one line (``sensing_cache``: ...).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable, NamedTuple

import numpy as np

from roadtrack import sensors

from ..scenario.spec import Scenario


class SensingContext(NamedTuple):
    """What a sensor knows of the run: the scenario, its roadside boxes static (R, 7) (None when the frames are read
    from a sensing cache), the perception's road map (sensors.RoadMap) and a Stopwatch charged per stage, or None."""

    scn: Scenario
    static: np.ndarray | None
    road: sensors.RoadMap | None
    watch: Any = None


@dataclass(frozen=True)
class Sensor:
    """A sensor: ``name`` (its registry name: lower-case letters, digits, hyphens), ``sense``, ``visibility``, ``pd``
    (None: the tracker gets no P_D from it), ``streams`` (the random streams it draws from; default
    ``("sensor.<name>",)``; only the LiDAR keeps the historical ``lidar`` and ``clutter``) and ``measurements``
    (None: a tracker cannot take its data; else ``measurements(ctx, truth, data) -> Measurements``, the detections
    with their measurement model, the sensor's pose from the ego's in ``truth``). The signatures are in the module
    docstring."""

    name: str
    sense: Callable[..., Any]
    visibility: Callable[..., tuple[np.ndarray, np.ndarray]]
    pd: Callable[..., Callable | None] | None = None
    streams: tuple[str, ...] = field(default=())
    doc: str = ""
    measurements: Callable[..., "Measurements"] | None = None

    def __post_init__(self) -> None:
        if not self.streams:
            object.__setattr__(self, "streams", (f"sensor.{self.name}",))


class Measurements(NamedTuple):
    """One sensor's detections of a frame as a tracker takes them (``tracker.sensors``), each carrying its
    measurement model: z (M, m) in the model's space; model a trackers.models measurement model (h, its Jacobian,
    R, residual, the sensor's pose of the frame); R (M, m, m) the detections' own covariances or None (the model's
    R); pd the sensor's nominal detection probability; clutter_density its clutter density in the measurement
    space's units (e.g. 1 / (m rad m/s) for range, azimuth, range-rate)."""

    z: np.ndarray
    model: Any
    R: np.ndarray | None
    pd: float
    clutter_density: float


class SensorReading(NamedTuple):
    """One frame of a sensor other than the LiDAR: its data, its visibility (n_hits (K,) int64, in_view (K,) bool)
    and its P_D function or None."""

    data: Any
    visibility: tuple[np.ndarray, np.ndarray]
    pd: Callable | None


def table_problem(data: Any) -> str | None:
    """Why the sensing cache cannot store ``data`` (one line), or None when it is a table: a dict of str -> numeric
    np.ndarray (bool, integer or float) with one common first dimension."""
    if not isinstance(data, dict):
        return f"it is a {type(data).__name__}, not a dict of column name -> NumPy array"
    rows = None
    for col, a in data.items():
        if not isinstance(col, str) or not isinstance(a, np.ndarray):
            return f"column {col!r} is a {type(a).__name__}, not a NumPy array named by a str"
        if a.ndim == 0 or a.dtype.kind not in "biuf":
            return f"column {col!r} has dtype {a.dtype} and {a.ndim} dimensions (allowed: bool, int, float; >= 1)"
        if rows is not None and len(a) != rows:
            return f"column {col!r} has {len(a)} rows, another {rows}"
        rows = len(a)
    return None
