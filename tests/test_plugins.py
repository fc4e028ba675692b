"""Plug-ins by entry points: a pip-installed package adds a filter, an associator and a whole tracker.

tests/fixtures/demo_plugin is installed with pip (offline, into a temporary folder put on PYTHONPATH of the
commands run here, so the suite's own environment never changes) and then used through the command line: listed
by `testbed trackers` and `testbed keys`, run in combinations with the built-ins, and a broken or name-taking
entry point is skipped with one warning line.
"""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

REPO = Path(__file__).resolve().parent.parent
TESTBED = [sys.executable, "-m", "roadtrack.testbed.cli.main"]


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    target = tmp_path_factory.mktemp("plugin-site")
    source = tmp_path_factory.mktemp("plugin-source") / "demo_plugin"  # the build leaves build/ beside its source
    shutil.copytree(REPO / "tests" / "fixtures" / "demo_plugin", source)
    subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--no-build-isolation", "--no-index",
                    "--target", str(target), str(source)],
                   check=True, capture_output=True, text=True, timeout=300)
    return target


def _testbed(site: Path, *args: str, cwd: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(site), str(REPO)]), "RERUN_ANALYTICS": "0"}
    return subprocess.run([*TESTBED, *args], capture_output=True, text=True, env=env, cwd=cwd, timeout=600)


def test_the_installed_plugin_is_listed_and_its_bad_entries_are_skipped_in_one_line(site, tmp_path):
    out = _testbed(site, "trackers", cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    for name in ("jpda-inflated-kf", "pda-inflated-kf", "strongest-kf", "strongest-svsf", "demo-nearest",
                 "stonesoup-jpda-kf"):
        assert f"\n{name} " in out.stdout, name
    warnings = [line for line in out.stderr.splitlines() if line]
    assert len(warnings) == 2 and all(w.startswith("warning: plug-in skipped: roadtrack.filters") for w in warnings)
    assert any("'kf' is already a filter" in w for w in warnings)  # a plug-in never replaces a built-in
    assert any("'broken'" in w and "AttributeError" in w for w in warnings)
    keys = _testbed(site, "keys", cwd=tmp_path)
    assert keys.returncode == 0 and "r_scale" in keys.stdout and "inflated-kf" in keys.stdout


def test_a_plugin_filter_runs_with_a_builtin_associator_and_its_parameter_is_checked(site, tmp_path):
    run = _testbed(site, "run", "cut_in_out", "--tracker", "jpda-inflated-kf", "--set", "duration_s=3",
                   "--set", "tracker.filter.r_scale=3.0", "--no-record", "--out", str(tmp_path / "a"), cwd=tmp_path)
    assert run.returncode == 0, run.stderr
    scores = json.loads((tmp_path / "a" / "scores.json").read_text())
    assert scores["tracker"] == "jpda-inflated-kf" and scores["scores"]["cars_seen"] == 3
    tracks = pd.read_parquet(tmp_path / "a" / "tracks.parquet")
    assert (tracks.status == "confirmed").any()
    bad = _testbed(site, "check", "cut_in_out", "--set", "tracker.name=jpda-inflated-kf",
                   "--set", "tracker.filter.r_scale=-1", cwd=tmp_path)
    errors = [line for line in bad.stderr.splitlines() if not line.startswith("warning: plug-in skipped")]
    assert bad.returncode == 2 and len(errors) == 1 and errors[0].startswith("error: tracker.filter.r_scale")
    huge = _testbed(site, "check", "cut_in_out", "--set", "tracker.name=jpda-inflated-kf",
                    "--set", "tracker.filter.r_scale=1e300", cwd=tmp_path)  # bounded like the built-ins' floats
    assert huge.returncode == 2 and "r_scale" in huge.stderr


def test_a_plugin_associator_and_a_plugin_tracker_run(site, tmp_path):
    run = _testbed(site, "run", "cut_in_out", "--tracker", "strongest-kf", "--set", "duration_s=3", "--no-record",
                   "--out", str(tmp_path / "s"), cwd=tmp_path)
    assert run.returncode == 0, run.stderr
    whole = _testbed(site, "run", "cut_in_out", "--tracker", "demo-nearest", "--set", "duration_s=2", "--no-record",
                     "--out", str(tmp_path / "n"), cwd=tmp_path)
    assert whole.returncode == 0, whole.stderr
    det = pd.read_parquet(tmp_path / "n" / "detections.parquet")
    tracks = pd.read_parquet(tmp_path / "n" / "tracks.parquet")
    assert len(tracks) == len(det) > 0  # that tracker reports every detection as a track
    assert json.loads((tmp_path / "n" / "scores.json").read_text())["tracker"] == "demo-nearest"


def test_without_the_plugin_its_names_are_unknown_in_one_line(tmp_path):
    out = subprocess.run([*TESTBED, "check", "cut_in_out", "--set", "tracker.name=jpda-inflated-kf"],
                         capture_output=True, text=True, cwd=tmp_path, timeout=120,
                         env={**os.environ, "PYTHONPATH": str(REPO)})
    assert out.returncode == 2 and "unknown tracker name 'jpda-inflated-kf'" in out.stderr
