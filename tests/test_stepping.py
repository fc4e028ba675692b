"""The batched traffic tick (testbed/world/stepping.py) against highway-env's own per-vehicle ``Road``: the same
numbers, bit for bit, on the highway benchmark's two-way IDM/MOBIL traffic, a curved road, and highway-env's
own environments (merge-v0 with its obstacle and crashes, highway-fast, roundabout, intersection, racetrack).

By default the highway benchmark runs its first 60 s (600 frames); ROADTRACK_FULL=1 runs all 427.4 s (4275
frames, about two minutes: the reference loop is O(N^2) in Python)."""
from __future__ import annotations

import copy
import os
import warnings

import numpy as np
import pytest
from highway_env.road.road import Road
from highway_env.vehicle.behavior import IDMVehicle

from roadtrack.testbed.scenario.spec import load_scenario
from roadtrack.testbed.world import simulation, stepping
from roadtrack.testbed.world.envsource import restore_vehicle_classes
from roadtrack.testbed.world.stepping import BatchRoad, batch_act, batch_step
from roadtrack.testbed.world.traffic import TrafficNetwork, TrafficRoad

FULL = bool(os.environ.get("ROADTRACK_FULL"))


def _trajectories(sim) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per frame: ids (K,) and [x, y, heading, vx, vy, lane, crashed] (K, 7)."""
    return [(f.ids.copy(), np.column_stack([f.xy, f.heading, f.velocity, f.lane, f.crashed]))
            for f in sim.frames()]


def _highway_env_reference(monkeypatch, scn):
    """The same scenario stepped by highway-env's own Road and RoadNetwork (no batching, no vectorised search)."""
    with monkeypatch.context() as m:
        m.setattr(simulation, "TrafficRoad", Road)
        m.setattr(simulation, "BatchRoad", Road)
        m.setattr(TrafficNetwork, "of", classmethod(lambda cls, net: net))
        sim = simulation.Simulation(scn)
        assert type(sim.road) is Road and type(sim.network).__name__ == "RoadNetwork"
        return _trajectories(sim)


def _assert_same(fast, slow) -> None:
    assert len(fast) == len(slow)
    for k, ((ia, a), (ib, b)) in enumerate(zip(fast, slow)):
        np.testing.assert_array_equal(ia, ib, err_msg=f"vehicle ids at frame {k}")
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-9, err_msg=f"frame {k}")


@pytest.mark.slow
def test_highway_benchmark_traffic_equals_highway_env(monkeypatch):
    scn = load_scenario("highway_benchmark", {} if FULL else {"duration_s": 60.0})
    sim = simulation.Simulation(scn)
    assert isinstance(sim.road, TrafficRoad) and isinstance(sim.road, BatchRoad)
    fast = _trajectories(sim)
    slow = _highway_env_reference(monkeypatch, scn)
    _assert_same(fast, slow)
    assert max(len(ids) for ids, _ in fast) > 30  # the batched path ran (BATCH_MIN_VEHICLES = 8)
    lanes = np.concatenate([a[:, 5] for _, a in fast])
    assert len(np.unique(lanes)) == 4  # lane changes happened: MOBIL's decisions are part of the check


def test_curved_road_with_scripted_vehicles_equals_highway_env(monkeypatch):
    monkeypatch.setattr(stepping, "BATCH_MIN_VEHICLES", 0)  # batch even the scenario's five vehicles
    scn = load_scenario("straight_curve")
    fast = _trajectories(simulation.Simulation(scn))
    slow = _highway_env_reference(monkeypatch, scn)
    _assert_same(fast, slow)
    heading = np.concatenate([a[:, 2] for _, a in fast])
    assert np.ptp(heading) > np.deg2rad(30)  # the cars went round the arc


@pytest.mark.parametrize("env_id", ["merge-v0", "highway-fast-v0", "roundabout-v0", "intersection-v0",
                                    "racetrack-v0"])
def test_highway_env_environments_step_the_same(monkeypatch, env_id):
    """Each env's road after reset, stepped 300 ticks by Road and by the batch: equal to 1e-9 (issue 19's bound:
    with numpy 2.4.6 racetrack-v0 differs by one ulp at tick 253, a different summation order), crashes and
    lanes identical."""
    import gymnasium as gym

    from roadtrack.testbed.scenario.env import gymnasium_with_envs

    gymnasium_with_envs()
    monkeypatch.setattr(stepping, "BATCH_MIN_VEHICLES", 0)
    classes = [c for c in IDMVehicle.__mro__ if c is not object]
    restore_vehicle_classes(classes)  # intersection-v0 retunes IDMVehicle's constants: put them back after
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            env = gym.make(env_id).unwrapped
            env.reset(seed=3)
        _step_both(env, env_id)
        env.close()
    finally:
        restore_vehicle_classes(classes)


def _step_both(env, env_id: str) -> None:
    ref, new = copy.deepcopy(env.road), copy.deepcopy(env.road)
    dt = 1 / env.config["simulation_frequency"]
    for k in range(300):
        Road.act(ref)
        Road.step(ref, dt)
        batch_act(new)
        batch_step(new, dt)
        a = np.array([[*v.position, v.heading, v.speed, v.crashed] for v in ref.vehicles])
        b = np.array([[*v.position, v.heading, v.speed, v.crashed] for v in new.vehicles])
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-9, err_msg=f"{env_id} tick {k}")  # issue 19: to 1e-9
        assert [v.lane_index for v in ref.vehicles] == [v.lane_index for v in new.vehicles]


def test_few_vehicles_are_stepped_by_highway_env_itself():
    scn = load_scenario("cut_in_out")
    sim = simulation.Simulation(scn)
    assert type(sim.road) is BatchRoad and len(sim.road.vehicles) < stepping.BATCH_MIN_VEHICLES
    assert not stepping.batchable(sim.road)


def test_front_vehicle_ties_go_to_the_last_as_in_highway_env():
    s = np.array([[0.0], [5.0], [5.0], [9.0]])
    on = np.ones((4, 1), dtype=bool)
    front = stepping.front_vehicles(np.array([0, 3, 1]), np.zeros(3, np.int64), s, on)
    np.testing.assert_array_equal(front, [2, -1, 2])  # vehicle 1 sees 2 (same s, not itself); 0 sees the last
    on[2, 0] = False
    np.testing.assert_array_equal(stepping.front_vehicles(np.array([0]), np.zeros(1, np.int64), s, on), [1])
