"""Scenario files: every shipped one loads and simulates; malformed ones are rejected with a one-line error."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from roadtrack.testbed.config.strict import ConfigError
from roadtrack.testbed.scenario.spec import SCENARIO_DIR, apply_overrides, list_scenarios, load_scenario, parse_scenario, read_toml
from roadtrack.testbed.world.simulation import Simulation

SHIPPED = tuple(list_scenarios())  # every shipped scenario, a new one included without editing this file
SIMULATED_S = 10.0  # each is simulated for at most this long [s]
REPO = Path(__file__).resolve().parent.parent


def test_shipped_scenarios_are_listed():
    assert {"convoy", "cut_in_out", "u_turn", "interchange", "straight_curve", "highway_benchmark",
            "dense_motorway"} <= set(SHIPPED)
    assert sorted(SHIPPED) == sorted(p.stem for p in SCENARIO_DIR.glob("*.toml"))


@pytest.mark.parametrize("name", SHIPPED)
def test_shipped_scenario_loads_and_simulates(name):
    full = load_scenario(SCENARIO_DIR / f"{name}.toml")
    scn = load_scenario(SCENARIO_DIR / f"{name}.toml", {"duration_s": min(full.duration_s, SIMULATED_S)})
    assert scn.name == name
    assert scn.rate_hz == pytest.approx(10.0)
    frames = list(Simulation(scn).frames())
    assert len(frames) == scn.n_frames == int(round(scn.duration_s * 10)) + 1
    last = frames[-1]
    assert last.time == pytest.approx(scn.duration_s, abs=1e-9)
    assert not last.crashed.any(), "scripted traffic must not crash"
    # every scripted vehicle (the first rows; background traffic comes and goes) drove at roughly its speed
    # (nobody stuck): path length over the run
    ids = frames[0].ids[:len(scn.all_vehicles())]
    xy = np.stack([f.xy[[int(np.flatnonzero(f.ids == i)[0]) for i in ids]] for f in frames])
    travelled = np.linalg.norm(np.diff(xy, axis=0), axis=2).sum(axis=0)
    assert np.all(travelled > 0.3 * scn.duration_s * np.array([v.speed_mps for v in scn.all_vehicles()]))


def test_convoy_keeps_its_gap():
    scn = load_scenario(SCENARIO_DIR / "convoy.toml")
    last = list(Simulation(scn).frames())[-1]
    xs = np.sort(last.xy[1:, 0])[::-1]
    gaps = -np.diff(xs) - 5.0
    np.testing.assert_allclose(gaps, scn.convoy.gap_m, atol=1.0)


def test_cut_in_out_changes_lanes_on_time():
    scn = load_scenario(SCENARIO_DIR / "cut_in_out.toml")
    frames = list(Simulation(scn).frames())
    cutter = [v.name for v in scn.all_vehicles()].index("cutter")
    lane_at = {round(f.time, 1): int(f.lane[cutter]) for f in frames}
    assert lane_at[2.9] == 2 and lane_at[6.0] == 1 and lane_at[14.0] == 2


def test_same_seed_same_truth():
    scn = load_scenario(SCENARIO_DIR / "interchange.toml")
    a = np.stack([f.xy for f in Simulation(scn).frames()])
    b = np.stack([f.xy for f in Simulation(scn).frames()])
    np.testing.assert_array_equal(a, b)


def _base() -> dict:
    return read_toml(SCENARIO_DIR / "cut_in_out.toml")


@pytest.mark.parametrize("override, key, words", [
    ({"road.lanez": 3}, "road.lanez", "unknown key; allowed:"),
    ({"duration_s": "long"}, "duration_s", "expected a number"),
    ({"duration_s": -4.0}, "duration_s", "must be > 0"),
    ({"vehicles.1.gap_m": -2.0}, "vehicles[1].gap_m", "must be > 0"),
    ({"vehicles.1.behaviour": "teleport"}, "vehicles[1].behaviour", "allowed: idm, hold_speed, follow"),
    ({"road.kind": "spiral"}, "road.kind", "allowed: straight, curved, u_turn"),
    ({"vehicles.0.lane": 7}, "vehicles[0].lane", "allowed: 0..2"),
    ({"tracker.name": "foo-kf"}, "tracker.name", "jpda"),
    ({"sensor.lidar.max_range_m": "far"}, "sensor.lidar.max_range_m", "expected a number"),
    ({"seed": True}, "seed", "expected an integer"),
])
def test_malformed_values_are_rejected_with_their_dotted_key(override, key, words):
    with pytest.raises(ConfigError) as info:
        parse_scenario(apply_overrides(_base(), override))
    msg = str(info.value)
    assert msg.startswith(key + ":"), msg
    assert words in msg
    assert "\n" not in msg


def test_follow_without_gap_is_rejected():
    data = apply_overrides(_base(), {"vehicles.0.behaviour": "follow"})
    with pytest.raises(ConfigError, match=r"^vehicles\[0\]\.gap_m: "):
        parse_scenario(data)


def test_cli_rejects_malformed_file_with_exit_2_and_writes_nothing(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text((SCENARIO_DIR / "convoy.toml").read_text().replace("gap_m = 10.0", "gap_m = -10.0"))
    out = tmp_path / "out"
    proc = subprocess.run([sys.executable, "-m", "roadtrack.testbed.cli.main", "run", str(bad), "--out", str(out)],
                          capture_output=True, text=True, cwd=REPO, timeout=120)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert lines == ["error: convoy.gap_m: -10.0 is not allowed; must be > 0"]
    assert not out.exists()


def test_invalid_toml_syntax_is_one_line(tmp_path):
    bad = tmp_path / "broken.toml"
    bad.write_text("name = \n")
    with pytest.raises(ConfigError) as info:
        load_scenario(bad)
    assert "not valid TOML" in str(info.value) and "\n" not in str(info.value)
