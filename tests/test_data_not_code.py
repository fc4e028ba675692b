"""Scenario and campaign files are data (issue 16): they never name code that is imported or run, by
`check`, `run` or `campaign check`; `[env.config]` is finite and bounded; a user's own ego policy comes only
from `--policy` (typed by the user) or the Python API, and a bad action it returns is a run-time error."""
from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import pytest

from roadtrack.testbed.cli.main import main
from roadtrack.testbed.config.strict import ConfigError
from roadtrack.testbed.scenario.spec import SCENARIO_DIR, apply_overrides, parse_scenario, read_toml

REPO = Path(__file__).resolve().parent.parent
TESTBED = Path(sys.executable).parent / "testbed"  # the console script: sys.path[0] is its folder, not the cwd
PROBE = '''
import pathlib
pathlib.Path(__file__).with_name("IMPORTED").write_text("the probe module was imported")
def f(observation, info):
    return "IDLE"
class Car:
    pass
'''


def _env_scenario(tmp: Path, env_lines: str, name: str = "shared") -> Path:
    path = tmp / f"{name}.toml"
    path.write_text(f'name = "{name}"\nduration_s = 1.0\n\n[env]\nid = "highway-v0"\n{env_lines}\n')
    return path


def _testbed(cwd: Path, *args: str, timeout: float = 120) -> tuple[int, str, list[str]]:
    proc = subprocess.run([str(TESTBED), *args], cwd=cwd, capture_output=True, text=True, timeout=timeout,
                          env={"PATH": "/usr/bin:/bin", "HOME": str(cwd), "RERUN_ANALYTICS": "0"})
    return proc.returncode, proc.stdout, [line for line in proc.stderr.splitlines() if line.strip()]


@pytest.mark.parametrize("env_lines, key", [
    ('policy = "probe_rt:f"', "env.policy"),
    ('policy = "builtins:exec"', "env.policy"),
    ('policy = "os:system"', "env.policy"),
    ('policy = "this:s"', "env.policy"),
    ('config = { other_vehicles_type = "probe_rt.Car" }', "env.config.other_vehicles_type"),
    ('config = { other_vehicles_type = "os.system" }', "env.config.other_vehicles_type"),
])
def test_a_shared_file_naming_code_is_refused_by_every_command_and_nothing_is_imported(tmp_path, env_lines, key):
    (tmp_path / "probe_rt.py").write_text(PROBE)
    scn = _env_scenario(tmp_path, env_lines)
    campaign = tmp_path / "camp.toml"
    campaign.write_text(f'name = "camp"\nscenarios = ["{scn.name}"]\ntrackers = ["jpda-kf"]\nseeds = 1\n')
    for args in (["check", scn.name], ["run", scn.name, "--no-record", "--quiet", "--out", "o"],
                 ["campaign", "run", campaign.name, "--out", "c"], ["check", campaign.name]):
        code, out, err = _testbed(tmp_path, *args)
        assert code == 2 and len(err) == 1, (args, code, err)
        assert err[0].startswith("error: ") and key in err[0], (args, err)
        assert "Beautiful is better than ugly" not in out  # `this` was not imported
        assert not (tmp_path / "IMPORTED").exists(), f"{args} imported the probe module from the working directory"
    assert not (tmp_path / "o").exists() and not (tmp_path / "c").exists()


def test_the_working_directory_is_never_put_on_sys_path(tmp_path, monkeypatch, capsys):
    (tmp_path / "probe_rt.py").write_text(PROBE)
    monkeypatch.chdir(tmp_path)
    before = list(sys.path)
    scn = _env_scenario(tmp_path, 'policy = "idle"')
    assert main(["check", str(scn)]) == 0
    assert sys.path == before and not (tmp_path / "IMPORTED").exists()
    assert main(["run", str(scn), "--policy", "probe_rt:f", "--no-record", "--quiet", "--out", "o"]) == 2
    assert "cannot import 'probe_rt'" in capsys.readouterr().err  # a module name is not looked up in the cwd


@pytest.mark.parametrize("config, words", [
    ({"lanes_count": 10**9}, "env.config.lanes_count: 1000000000 is not allowed; must be in 1..8 lanes"),
    ({"lanes_count": 1e9}, "env.config.lanes_count: expected an integer"),
    ({"vehicles_count": -1}, "env.config.vehicles_count: -1 is not allowed; must be >= 0"),
    ({"vehicles_count": 10**9}, "env.config.vehicles_count: 1000000000 vehicles is above the limit"),
    ({"duration": float("nan")}, "env.config.duration: expected a finite number, got nan"),
    ({"duration": 1e9}, "env.config.duration: 1000000000 s is above the limit"),
    ({"vehicles_density": float("inf")}, "env.config.vehicles_density: expected a finite number"),
    ({"collision_reward": 1e300}, "env.config.collision_reward: 1e+300 is not allowed; numbers in env.config"),
    ({"screen_width": "wide"}, "env.config.screen_width: expected a number"),
    ({"observation": {"type": "OccupancyGrid", "grid_step": [1e-4, 1e-4]}}, "env.config.observation.grid_step: "
                                                                            "the grid has"),
])
def test_env_config_numbers_are_finite_and_bounded_and_refused_at_once(config, words):
    t0 = time.perf_counter()
    with pytest.raises(ConfigError) as info:
        parse_scenario({"name": "t", "duration_s": 2.0, "env": {"id": "highway-v0", "config": config}})
    assert time.perf_counter() - t0 < 1.0 + 1.5  # within a second (plus highway-env's first import)
    assert str(info.value).startswith(words) and "\n" not in str(info.value), str(info.value)


def test_every_env_accepts_its_own_default_config():
    from roadtrack.testbed.scenario.envcheck import check_env_config
    from roadtrack.testbed.scenario.env import env_class, env_ids

    for env_id in env_ids():
        defaults = env_class(env_id).default_config()
        check_env_config(defaults, defaults)  # no ConfigError


def test_a_sigma_v_that_overflowed_at_frame_2_is_refused_by_check(capsys):
    assert main(["check", "convoy", "--set", "tracker.filter.sigma_v=1e308"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "tracker.filter.sigma_v: 1e+308 is not allowed" in err[0]


LEFT = '''
def drive(observation, info):
    return "LANE_LEFT" if info["frame"] == 5 else "IDLE"
def jump(observation, info):
    return "JUMP" if info["frame"] == 3 else "IDLE"
'''


def test_policy_option_drives_the_ego_and_a_bad_action_is_a_run_time_error(tmp_path, capsys):
    (tmp_path / "my_policy.py").write_text(LEFT)
    scn = _env_scenario(tmp_path, 'config = { vehicles_count = 3, initial_lane_id = 2 }')
    out = tmp_path / "run"
    base = ["run", str(scn), "--no-record", "--quiet", "--out", str(out)]
    assert main([*base, "--policy", f"{tmp_path / 'my_policy.py'}:drive"]) == 0
    import pyarrow.parquet as pq

    truth = pq.read_table(out / "truth.parquet").to_pandas()
    ego_y = truth[truth.is_ego].sort_values("frame").y.to_numpy()
    assert abs(ego_y[0] - 8.0) < 0.05 and abs(ego_y[-1] - 8.0) > 1.0  # lane 2 centre, then moving left
    capsys.readouterr()
    assert main([*base, "--policy", f"{tmp_path / 'my_policy.py'}:jump"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "the ego policy jump returned 'JUMP' is not an action of highway-v0" in err[0], err
    assert (out / "INCOMPLETE").exists()  # the frames before it are kept
    assert main(["run", "convoy", "--policy", f"{tmp_path / 'my_policy.py'}:drive", "--quiet"]) == 2
    assert "has no [env] table" in capsys.readouterr().err


def test_docs_limits_md_lists_the_env_config_bounds():
    from roadtrack.testbed.scenario.envcheck import bounds_markdown

    assert bounds_markdown() in (REPO / "docs" / "limits.md").read_text(), \
        "docs/limits.md is stale: paste testbed.scenario.envcheck.bounds_markdown() into it"
