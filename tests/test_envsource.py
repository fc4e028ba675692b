"""highway-env environments as traffic sources (testbed/world/envsource.py): shipped scenarios end to end, seeding,
scripted and callable ego policies, stable vehicle ids, early episode ends and one-line config errors."""
from __future__ import annotations

import dataclasses
import types
from pathlib import Path

import numpy as np
import pytest

from roadtrack.testbed.config.strict import ConfigError
from roadtrack.testbed.scenario.env import EnvSpec, env_ids
from roadtrack.testbed.world.envsource import EnvSimulation, EpisodeEndWarning, env_config, vehicle_height
from roadtrack.testbed.world.roadside import roadside_boxes
from roadtrack.testbed.pipeline.run import run_scenario
from roadtrack.testbed.sensing import rng_streams
from roadtrack.testbed.scenario.spec import SCENARIO_DIR, apply_overrides, load_scenario, parse_scenario, read_toml
from roadtrack.testbed import world
from roadtrack.testbed.world.simulation import road_edges, roadside_objects

REPO = Path(__file__).resolve().parent.parent
HIGHWAY = {"id": "highway-v0", "config": {"vehicles_count": 5, "initial_lane_id": 2}}  # ego in lane 2 of 0..3


def left_at_one_second(observation, info):
    """A user policy (given through the Python API or `--policy`): one lane change left."""
    assert np.isfinite(info["time_s"]) and info["frame"] >= 0
    return "LANE_LEFT" if info["frame"] == 10 else "IDLE"


def _scenario(env: dict, duration_s: float = 4.0, seed: int = 1, **extra) -> object:
    return parse_scenario({"name": "t", "seed": seed, "duration_s": duration_s, "env": env, **extra})


def _ego_y(scn, policy=None) -> np.ndarray:
    return np.array([f.xy[0, 1] for f in EnvSimulation(scn, policy).frames()])


@pytest.mark.parametrize("name", ["merge", "roundabout"])
def test_shipped_env_scenario_runs_end_to_end_with_vehicle_detections(name):
    scn = load_scenario(SCENARIO_DIR / f"{name}.toml", {"duration_s": 6.0})
    res = run_scenario(scn, out_dir=None, record=False)
    assert res.n_frames == 61
    truth, dets = res.tables["truth"], res.tables["detections"]
    others = ~truth.array("is_ego")
    assert len(np.unique(truth.array("vehicle_id")[others])) == 4  # both envs start with 4 other cars
    heights = truth.array("height")
    np.testing.assert_allclose(heights, 1.6, atol=1e-12)
    from_vehicles = dets.array("provenance") >= 0
    assert from_vehicles.sum() / res.n_frames >= 1.5, "cars must come within LiDAR range and be detected"
    assert len(np.unique(dets.array("provenance")[from_vehicles])) >= 2
    assert res.scores.correct_tracks >= 1


@pytest.mark.parametrize("name, at_least, removed", [("merge", 300, 9), ("roundabout", 400, 250)])
def test_env_roadside_objects_stay_off_the_lanes(name, at_least, removed):
    """With the default [roadside], the boxes highway-env's lane borders put on lanes (shared borders of
    opposite lanes, the ramp's join, the ring) are left out, and every other box is kept."""
    scn = load_scenario(SCENARIO_DIR / f"{name}.toml", {"roadside": {}})
    sim = EnvSimulation(scn)
    sim.close()
    boxes = roadside_objects(sim.network, scn.roadside, rng_streams(scn.seed)["roadside"])
    every = roadside_boxes(road_edges(sim.network), scn.roadside, rng_streams(scn.seed)["roadside"])
    assert len(boxes) >= at_least and len(every) - len(boxes) >= removed
    lanes = [ln for to in sim.network.graph.values() for group in to.values() for ln in group]
    on_lane = 0
    for b in boxes:
        for ln in lanes:
            s, lat = ln.local_coordinates(b[:2])
            if 0.0 <= s <= ln.length and abs(lat) <= ln.width_at(s) / 2 + 0.5 * min(b[2], b[3]):
                on_lane += 1
                break
    assert on_lane == 0


def test_same_seed_same_truth_other_seed_other_truth():
    env = {"id": "merge-v0", "policy": "idm"}
    a, b, c = (np.stack([f.xy for f in EnvSimulation(_scenario(env, 3.0, seed)).frames()]) for seed in (4, 4, 5))
    np.testing.assert_array_equal(a, b)
    assert a.shape == c.shape == (31, 5, 2)
    assert np.max(np.abs(a[:, 1:] - c[:, 1:])) > 1.0  # merge-v0 draws lanes +-5 m and speeds +-1 m/s


def test_config_merges_over_the_env_defaults_and_one_step_is_one_frame():
    speeds = [0.0, 4.0, 8.0, 12.0, 16.0]
    scn = _scenario({"id": "roundabout-v0", "config": {"action": {"target_speeds": speeds}}}, 2.0,
                    physics_substeps=3)
    cfg = env_config(scn)
    assert cfg["action"] == {"type": "DiscreteMetaAction", "target_speeds": speeds}  # merged, type kept
    assert (cfg["policy_frequency"], cfg["simulation_frequency"]) == (10, 30)
    assert cfg["duration"] == pytest.approx(3.0, abs=1e-12)  # beyond the scenario's 2 s
    other = dataclasses.replace(scn, env=EnvSpec(id="roundabout-v0", config={"action": {"type": "ContinuousAction"}}))
    assert env_config(other)["action"] == {"type": "ContinuousAction"}  # another type replaces the table
    sim = EnvSimulation(scn)
    frames = list(sim.frames())
    assert len(frames) == 21 and sim.env.unwrapped.time == pytest.approx(2.0, abs=1e-9)
    assert sim.env.unwrapped.steps == 60  # physics ticks: 20 steps x 3 substeps


def test_scripted_lane_change_moves_the_ego_one_lane_left():
    idle = _ego_y(_scenario(HIGHWAY))
    left = _ego_y(_scenario({**HIGHWAY, "actions": [{"at_s": 1.0, "action": "LANE_LEFT"}]}))
    np.testing.assert_allclose(idle, 8.0, atol=0.05)  # lane 2 centre, 4 m lanes
    np.testing.assert_allclose(left[:11], 8.0, atol=0.05)  # nothing before t = 1.0 s
    assert left[-1] == pytest.approx(4.0, abs=0.1)  # lane 1 centre, 3 s later


def test_callable_policy_from_the_python_api():
    y = _ego_y(_scenario(HIGHWAY), policy=left_at_one_second)
    np.testing.assert_allclose(y[:11], 8.0, atol=0.05)
    assert y[-1] == pytest.approx(4.0, abs=0.1)


def test_load_policy_from_a_file_path_or_a_module_name():
    """`--policy path/to/file.py:function` loads that file; `module:function` an importable module."""
    from roadtrack.testbed.world.envsource import load_policy

    f = load_policy(str(REPO / "tests" / "test_envsource.py") + ":left_at_one_second")
    assert f(None, {"time_s": 1.0, "frame": 10}) == "LANE_LEFT"
    assert load_policy("roadtrack.testbed.world.envsource:idle_action").__name__ == "idle_action"
    for bad, words in (("nope", "expected module:function"), ("no_such_module_x:f", "cannot import 'no_such_module_x'"),
                       ("roadtrack.testbed.world.envsource:no_such_fn", "has no attribute 'no_such_fn'"),
                       ("missing_file.py:f", "missing_file.py: no such file")):
        with pytest.raises(ConfigError) as info:
            load_policy(bad)
        assert str(info.value).startswith("--policy: ") and words in str(info.value), str(info.value)


def test_idle_on_continuous_actions_keeps_the_lane():
    scn = _scenario({"id": "racetrack-oval-v0"}, duration_s=8.0)
    sim = EnvSimulation(scn)
    u = sim.env.unwrapped
    lateral = []
    for _ in sim.frames():
        lane = u.road.network.get_lane(u.vehicle.lane_index)
        lateral.append(lane.local_coordinates(u.vehicle.position)[1])
    assert len(lateral) == 81
    assert np.max(np.abs(lateral)) < 0.5  # [m]; zero steering would leave the oval's curve


def test_vehicle_ids_are_stable_and_never_reused_when_vehicles_come_and_go():
    frames = list(EnvSimulation(_scenario({"id": "intersection-v0", "policy": "idm"}, 6.0, seed=1)).frames())
    assert all(f.ids[0] == 0 and len(np.unique(f.ids)) == len(f.ids) for f in frames)
    first, last = {}, {}
    for k, f in enumerate(frames):
        for i in f.ids:
            first.setdefault(int(i), k)
            last[int(i)] = k
    assert max(first) >= len(frames[0].ids) + 3  # vehicles spawned during the run got new ids
    for i in first:  # present in one unbroken run of frames, moving at most 25 m/s x 0.1 s per frame
        track = [f.xy[list(f.ids).index(i)] for f in frames[first[i]:last[i] + 1] if i in f.ids]
        assert len(track) == last[i] - first[i] + 1
        assert np.max(np.linalg.norm(np.diff(track, axis=0), axis=1), initial=0.0) <= 2.5


def test_intersection_leaves_the_idm_class_constants_as_they_were():
    from highway_env.vehicle.behavior import IDMVehicle

    before = (IDMVehicle.DISTANCE_WANTED, IDMVehicle.COMFORT_ACC_MAX, IDMVehicle.COMFORT_ACC_MIN)
    sim = EnvSimulation(_scenario({"id": "intersection-v0"}, 1.0))
    assert IDMVehicle.DISTANCE_WANTED == pytest.approx(7.0, abs=1e-12)  # intersection-v0's own tuning
    list(sim.frames())
    after = (IDMVehicle.DISTANCE_WANTED, IDMVehicle.COMFORT_ACC_MAX, IDMVehicle.COMFORT_ACC_MIN)
    np.testing.assert_allclose(after, before, atol=1e-12)


def test_a_crash_stops_the_run_with_a_warning_and_continue_steps_on():
    env = {"id": "merge-v0"}  # the idle ego rear-ends the car ahead at t = 3.7 s with seed 0
    with pytest.warns(EpisodeEndWarning, match=r"^merge-v0 terminated: the ego crashed at t = 3\.7 s"):
        res = run_scenario(_scenario(env, 5.0, seed=0), out_dir=None, record=False)
    assert res.n_frames == 38
    assert res.tables["truth"].array("crashed")[-5:].any()
    with pytest.warns(EpisodeEndWarning, match="stepping on"):
        frames = list(EnvSimulation(_scenario({**env, "on_end": "continue"}, 5.0, seed=0)).frames())
    assert len(frames) == 51
    assert frames[-1].crashed[0] and np.hypot(*frames[-1].velocity[0]) < 0.5 * np.hypot(*frames[37].velocity[0])


def test_height_by_length_and_height_attribute():
    cases = [(5.0, None, 1.6, "car"), (6.5, None, 2.5, "van"), (12.0, None, 3.5, "truck"), (12.0, 4.0, 4.0, "truck")]
    for length, attr, height, kind in cases:
        v = types.SimpleNamespace(LENGTH=length, **({} if attr is None else {"HEIGHT": attr}))
        h, k = vehicle_height(v)
        assert h == pytest.approx(height, abs=1e-12) and k == kind


def _merge_data() -> dict:
    return read_toml(SCENARIO_DIR / "merge.toml")


@pytest.mark.parametrize("override, key, words", [
    ({"env.id": "merge-v9"}, "env.id", "allowed: exit-v0,"),
    ({"env.id": "lane-keeping-v0"}, "env.id", "takes no render_mode"),
    ({"env.policy": "drive"}, "env.policy", "must be idle or idm: a scenario file names no code"),
    ({"env.policy": "roadtrack.testbed.world.envsource:idle_action"}, "env.policy", "must be idle or idm"),
    ({"env.policy": "idle", "env.actions": [{"at_s": 1.0, "action": "JUMP"}]}, "env.actions[0].action",
     "'JUMP' is not an action of merge-v0; allowed: LANE_LEFT, IDLE, LANE_RIGHT, FASTER, SLOWER, 0..4"),
    ({"env.policy": "idle", "env.actions": [{"at_s": 1.0, "action": [0.5, 0.1]}]}, "env.actions[0].action",
     "is not an action of merge-v0"),
    ({"env.actions": [{"at_s": 1.0, "action": 1}]}, "env.actions", "policy 'idm' ignores actions"),
    ({"env.config.lanez": 3}, "env.config.lanez", "unknown key for merge-v0; allowed:"),
    ({"env.config.policy_frequency": 1}, "env.config.policy_frequency", "is set from rate_hz"),
    ({"env.config.other_vehicles_type": "nowhere.Car"}, "env.config.other_vehicles_type",
     "'nowhere.Car' is not one of highway-env's vehicle classes"),
    ({"env.on_end": "pause"}, "env.on_end", "allowed: stop, continue"),
    ({"vehicles": [{"lane": 0}]}, "vehicles", "not used with env"),
    ({"road.kind": "curved"}, "road", "not used with env"),
    ({"rate_hz": 12.5}, "rate_hz", "whole number of Hz"),
])
def test_malformed_env_scenarios_give_one_line_errors_naming_the_key(override, key, words):
    """The spec's checks and the world's (the env built and stepped once): testbed.world.parse_scenario, what
    `testbed check` and `testbed run` load with."""
    with pytest.raises(ConfigError) as info:
        world.parse_scenario(apply_overrides(_merge_data(), override))
    msg = str(info.value)
    assert msg.startswith(key + ":"), msg
    assert words in msg and "\n" not in msg


def test_supported_ids_include_the_documented_ones():
    ids = env_ids()
    assert {"highway-v0", "merge-v0", "roundabout-v0", "intersection-v0", "u-turn-v0"} <= set(ids)
    assert "lane-keeping-v0" not in ids and len(ids) >= 25
