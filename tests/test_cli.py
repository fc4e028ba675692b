"""The `testbed` command line: listings, --set overrides, clear errors, the generated key reference."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from roadtrack.testbed.config.strict import parse_sets
from roadtrack.testbed.config.strict import ConfigError
from roadtrack.testbed.cli.keys import keys_markdown

REPO = Path(__file__).resolve().parent.parent


def _cli(*args: str, timeout: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "roadtrack.testbed.cli.main", *args], capture_output=True, text=True, cwd=REPO,
                          timeout=timeout, env=dict(os.environ, RERUN_ANALYTICS="0"))


def test_docs_scenarios_md_is_generated_from_the_code():
    assert (REPO / "docs" / "scenarios.md").read_text() == keys_markdown(), \
        "docs/scenarios.md is stale: run `.venv/bin/testbed keys > docs/scenarios.md`"


def test_keys_reference_lists_nested_keys_with_defaults():
    md = keys_markdown()
    for key in ("`vehicles[].lane_changes[].at_s`", "`sensor.lidar.max_range_m`", "`convoy.gap_m`",
                "`sensor.perception.ground.method`", "`tracker.filter`", "`tracker.associator.gate_alpha`", "`tracker.management.coast_scans`", "`scoring.match_distance_m`"):
        assert key in md, key
    assert "| `sensor.lidar.max_range_m` | float | preset (`70.0`) |" in md  # the HDL-32E preset's value


def test_parse_sets_reads_toml_values():
    got = parse_sets(["duration_s=5", "sensor.clutter.density_per_m2=1e-2", "tracker.name=pda-kf",
                       "roadside.barriers=false", "vehicles.0.lane_changes=[{at_s = 1.0, lane = 0}]"])
    assert got == {"duration_s": 5, "sensor.clutter.density_per_m2": 0.01, "tracker.name": "pda-kf",
                   "roadside.barriers": False, "vehicles.0.lane_changes": [{"at_s": 1.0, "lane": 0}]}
    with pytest.raises(ConfigError, match=r"^--set: 'oops': expected KEY=VALUE"):
        parse_sets(["oops"])


def test_listings():
    proc = _cli("scenarios")
    assert proc.returncode == 0
    names = [line.split()[0] for line in proc.stdout.splitlines()]
    assert names == sorted(["convoy", "cut_in_out", "interchange", "straight_curve", "u_turn", "highway_benchmark",
                            "merge", "roundabout", "dense_motorway"])
    assert "merge-v0" in proc.stdout and "motorway" in proc.stdout
    assert "INVALID" not in proc.stdout
    proc = _cli("trackers")
    assert proc.returncode == 0 and {"jpda-kf", "pda-kf", "gnn-kf", "nn-kf"} <= set(proc.stdout.split())


@pytest.mark.parametrize("args, message", [
    (["run", "nowhere.toml"], "error: nowhere.toml: no such scenario file (shipped: convoy, cut_in_out,"),
    (["run", "cut_in_out", "--tracker", "jpda-ukf"], "error: --tracker: unknown tracker 'jpda-ukf': a combination"),
    (["run", "cut_in_out", "--tracker", ""], "error: --tracker: unknown tracker '': a combination"),  # not ignored
    (["run", "cut_in_out", "--set", "sensor.lidar.max_range_m=-3"],
     "error: sensor.lidar.max_range_m: expected a finite number > 0, got -3.0"),
    (["run", "cut_in_out", "--set", "tracker.filter.sigma_q=1"], "error: tracker.filter.sigma_q: unknown key; allowed: detection_R, motion, "),
    (["run", "cut_in_out", "--set", "tracker.associator.pd=2"], "error: tracker.associator.pd: 2.0 is not allowed; must be in (0, 1]"),
    (["view", "no/such/run"], "error: no/such/run/run.rrd: no recording"),
])
def test_bad_input_is_one_line_and_exit_2(args, message, tmp_path):
    proc = _cli(*args, "--out", str(tmp_path / "o")) if args[0] == "run" else _cli(*args)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(message), lines
    assert not (tmp_path / "o").exists()


def test_a_run_that_fails_mid_way_keeps_its_tables_and_says_where(tmp_path):
    # JPDA told to refuse any cluster with more than one joint event, with gates wide enough to merge tracks
    out = tmp_path / "failed"
    proc = _cli("run", "cut_in_out", "--set", "duration_s=2", "--set", "tracker.associator.max_events=1",
                "--set", "tracker.associator.method='enumerate'", "--set", "tracker.associator.on_overflow='raise'", "--set", "tracker.associator.gate_alpha=1e4",
                "--out", str(out), "--quiet")
    assert proc.returncode == 1
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: JPDAOverflowError: "), lines
    assert "the run stopped at frame 2 (t = 0.2 s)" in lines[0]
    import pandas as pd

    truth = pd.read_parquet(out / "truth.parquet")
    assert sorted(truth.frame.unique()) == [0, 1]  # the frames before the failure
    assert (out / "run.rrd").is_file() and not (out / "scores.json").exists()
