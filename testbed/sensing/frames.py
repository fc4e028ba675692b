"""The one sensing loop: ``sense(scenario)`` yields, per frame, the truth, the LiDAR scan, the perception's result,
the detections (with the scenario's added clutter), the cars' visibility and the occlusion-aware P_D, and the data
of the scenario's further sensors (``sensor.extra``; testbed/sensing/sensor.py says what a sensor is).

Random streams derive from the scenario seed by name (testbed/common/streams.py), one per consumer, so switching
on added clutter does not change the LiDAR noise and a new sensor changes no existing stream.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Iterator

import numpy as np

from roadtrack import sensors

from ..common.streams import Streams
from ..scenario.spec import Scenario
from ..world.simulation import lane_centres, roadside_objects
from .lidar import (PD_RANGE_STEP_M, TRUCK_BOX_M, empty_scan, frame_scan, occlusion_pd,  # noqa: F401 - re-exported
                    pd_scan, perceive_frame, scan_frame, sense_frame, visibility)
from .registry import scenario_sensors
from .sensor import SensingContext, SensorReading

STREAMS = ("roadside", "lidar", "clutter")
"""The streams of the sensing setup and the LiDAR (roadside objects, LiDAR noise, added clutter), made up front by
:func:`rng_streams`; every other name is made on first use."""


@dataclass(frozen=True, eq=False)
class SensedFrame:
    """One frame of sensing.

    truth: the simulator's frame (testbed.world.simulation.Frame: ids, names, xy, velocity, heading, size, ...; row 0 the
    ego). scan: the LiDAR turn (sensors.Scan). perception: its sensors.PerceptionResult. detections: the
    sensors.Detections the tracker gets (perception's, then the added clutter). visibility: (n_points (K,) int64
    LiDAR points on each vehicle of truth, in_range (K,) bool centre within the LiDAR's range). pd: the
    occlusion-aware P_D ``pd(xy (T, 2), nominal, trucks=None) -> (T,)``, or None when the scenario has it off.
    pd_scan: the scan ``pd`` reads (:func:`pd_scan`: no points, the range image without ground returns in 2 mm
    steps), the same whether sensed live or read from a sensing cache. road: the perception's lane map
    (sensors.RoadMap), the same live or cached, or None. others: the further sensors' frames by name
    (testbed.sensing.sensor.SensorReading: data, visibility, pd), the same live or cached; empty by default.
    """

    truth: object
    scan: sensors.Scan
    perception: sensors.PerceptionResult
    detections: sensors.Detections
    visibility: tuple[np.ndarray, np.ndarray]
    pd: Callable[..., np.ndarray] | None
    pd_scan: sensors.Scan | None = None
    road: sensors.RoadMap | None = None
    others: dict[str, SensorReading] = field(default_factory=dict)

    @property
    def index(self) -> int:
        return int(self.truth.frame)

    @property
    def time(self) -> float:
        return float(self.truth.time)


def sense(scn: Scenario, policy: Callable | None = None, watch=None) -> Iterator[SensedFrame]:
    """The frames of ``scn`` sensed one by one (the scenario's traffic, its ego driven by ``policy`` for a scenario
    with ``[env]``). ``watch``: a Stopwatch charged per stage (simulation, raycast, perception), or None."""
    rngs = rng_streams(scn.seed)
    sim, static, road = sensing_setup(scn, rngs, policy)
    yield from sense_simulation(scn, sim, static, road, rngs, watch)


def sense_simulation(scn: Scenario, sim, static: np.ndarray, road: sensors.RoadMap, rngs: dict,
                     watch=None) -> Iterator[SensedFrame]:
    """:func:`sense` on a simulation already set up (:func:`sensing_setup`), e.g. to log its road first. Each
    sensor gets only its own streams of ``rngs`` (a :class:`~testbed.common.streams.Streams` makes missing ones)."""
    lidar, *extra = scenario_sensors(scn)
    ctx = SensingContext(scn, static, road, watch)
    pd_lidar = lidar.pd(ctx)
    pds = {s.name: s.pd(ctx) if s.pd is not None else None for s in extra}
    if extra and not isinstance(rngs, Streams):
        rngs, given = Streams(scn.seed), rngs
        rngs.update(given)
    for truth in sim.frames():
        if watch is not None:
            watch.lap("simulation")
        data = lidar.sense(ctx, truth, {n: rngs[n] for n in lidar.streams})
        others = {}
        for s in extra:
            got = s.sense(ctx, truth, {n: rngs[n] for n in s.streams})
            pd = pds[s.name]
            others[s.name] = SensorReading(got, s.visibility(ctx, truth, got), pd(got) if pd is not None else None)
        yield SensedFrame(truth, data.scan, data.perception, data.detections, lidar.visibility(ctx, truth, data),
                          pd_lidar(data) if pd_lidar is not None else None, data.pd_scan, road, others)


def rng_streams(seed: int) -> Streams:
    """The run's generators by name, derived from the scenario seed (testbed/common/streams.py): :data:`STREAMS`
    made up front, any other name made when first asked for."""
    return Streams(seed, STREAMS)


def sensing_setup(scn: Scenario, rngs: dict[str, np.random.Generator], policy: Callable | None = None):
    """The traffic source of ``scn`` (a highway-env environment with ``[env]``, its ego driven by ``policy`` when
    given, else our scripted traffic), its roadside boxes (K, 7) drawn from ``rngs["roadside"]`` and the
    perception's road map."""
    from ..world.envsource import make_simulation

    sim = make_simulation(scn, policy)
    centres = lane_centres(sim.network)  # sampled once for the roadside objects and the road map
    static = roadside_objects(sim.network, scn.roadside, rngs["roadside"], centres)
    return sim, static, road_map(sim.network, centres)


def road_map(network, centres: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None) -> sensors.RoadMap:
    """The perception's road map (lane centre lines and half widths) of a highway-env road network; ``centres``:
    its lane_centres when the caller has them already."""
    return sensors.RoadMap(*(centres if centres is not None else lane_centres(network)))


