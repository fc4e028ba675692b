"""Every option checked before any work (issue 16): `perception --write-settings` never replaces a file it did
not write nor runs a characterisation it cannot save, `reproduce --seed` has `run --seed`'s bounds, output
the terminal cannot encode is escaped; and every JSON file the tool writes is strict JSON (null, not NaN).

Other suites can reuse the strict check: ``from test_options_json import strict_json_files``."""
from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from roadtrack.testbed.cli.main import main
from roadtrack.testbed.common.jsonio import finite, json_text
from roadtrack.testbed.perception.report import SETTINGS_MARK
from roadtrack.testbed.scenario.spec import load_scenario

REPO = Path(__file__).resolve().parent.parent
FAST = ["--set", "sensor.lidar.azimuth_step_deg=1.0", "--quiet"]  # 11,520 rays per scan instead of 72,000
QUICK_PERCEPTION = ["perception", "convoy", "--duration", "0.5", "--no-ablation", "--no-merge-sweep", *FAST]


def _refuse_constant(name: str) -> Any:
    raise ValueError(f"not strict JSON: bare {name}")


def strict_json(text: str) -> Any:
    """``text`` parsed as strict JSON: ``NaN``, ``Infinity`` and ``-Infinity`` raise ValueError."""
    return json.loads(text, parse_constant=_refuse_constant)


def strict_json_files(folder: Path) -> dict[str, Any]:
    """Every ``*.json`` file under ``folder`` (relative path -> its data), each parsed by :func:`strict_json`."""
    return {str(p.relative_to(folder)): strict_json(p.read_text(encoding="utf-8"))
            for p in sorted(folder.rglob("*.json"))}


def _cli(capsys, *args: str) -> tuple[int, str, list[str]]:
    code = main(list(args))
    cap = capsys.readouterr()
    return code, cap.out, cap.err.strip().splitlines()


def _env(tmp_path: Path, **extra: str) -> dict:
    home = tmp_path / "home"
    return dict(os.environ, HOME=str(home), XDG_CONFIG_HOME=str(home / ".config"), PYTHONPATH=str(REPO),
                RERUN_ANALYTICS="0", **extra)


# --- perception --write-settings -------------------------------------------------------------------------------

def test_write_settings_onto_a_users_file_is_refused_before_the_characterisation(capsys, tmp_path):
    mine = tmp_path / "mine.toml"
    mine.write_text('name = "my own notes"\n')
    out = tmp_path / "report"
    t0 = time.perf_counter()
    code, _, err = _cli(capsys, *QUICK_PERCEPTION, "--out", str(out), "--write-settings", str(mine))
    elapsed = time.perf_counter() - t0
    assert code == 2 and len(err) == 1, err
    assert err[0] == (f"error: --write-settings: {mine} exists and was not written by `testbed perception "
                      "--write-settings`; it is left unchanged: choose another file, or remove it first")
    assert mine.read_text() == 'name = "my own notes"\n'
    assert elapsed < 2.0 and not out.exists() and sorted(p.name for p in tmp_path.iterdir()) == ["mine.toml"]


@pytest.mark.parametrize("target, why", [("folder", "is a folder"), ("new/", "ends with '/' (a folder)")])
def test_write_settings_onto_a_folder_is_refused_before_the_characterisation(capsys, tmp_path, target, why):
    (tmp_path / "folder").mkdir()
    given = str(tmp_path / target) + ("/" if target.endswith("/") else "")
    out = tmp_path / "report"
    t0 = time.perf_counter()
    code, _, err = _cli(capsys, *QUICK_PERCEPTION, "--out", str(out), "--write-settings", given)
    assert code == 2 and len(err) == 1 and time.perf_counter() - t0 < 2.0, err
    assert err[0].startswith(f"error: --write-settings: {given} {why}; give a file path")
    assert not out.exists() and list((tmp_path / "folder").iterdir()) == [] and not (tmp_path / "new").exists()


def test_write_settings_replaces_its_own_earlier_file(capsys, tmp_path):
    path = tmp_path / "measured.toml"
    for n in (1, 2):  # the second run replaces the file the first one wrote
        code, out, err = _cli(capsys, *QUICK_PERCEPTION, "--out", str(tmp_path / f"r{n}"), "--write-settings",
                              str(path))
        assert code == 0, err
        assert out.strip().splitlines()[-1].startswith(f"wrote {path} (tracker.associator.pd = ")
        first = path.read_text(encoding="utf-8").splitlines()[0]
        assert first.startswith(SETTINGS_MARK + ": convoy with the tracker settings it measured (")
    scn = load_scenario(path)
    assert scn.name == "convoy" and 0.0 < scn.tracker.associator["pd"] <= 1.0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["measured.toml", "r1", "r2"]  # no temporary left


# --- reproduce --seed ------------------------------------------------------------------------------------------

@pytest.mark.parametrize("seed", ["-1", "4294967296"])
def test_reproduce_seed_has_the_bounds_of_run_seed_and_makes_no_folder(capsys, tmp_path, seed):
    out = tmp_path / "a" / "rep"
    code, _, err = _cli(capsys, "reproduce", "seed-000", "--quick", "--quiet", "--seed", seed, "--out", str(out))
    assert code == 2 and err == [f"error: --seed: {seed} is not a seed; allowed: 0..4294967295 (2**32 - 1, "
                                 "numpy's range)"]
    assert list(tmp_path.iterdir()) == []


def test_reproduce_out_below_a_file_is_exit_2_and_makes_no_folder(capsys, tmp_path):
    (tmp_path / "f").write_text("x")
    code, _, err = _cli(capsys, "reproduce", "seed-000", "--quick", "--quiet", "--out", str(tmp_path / "f" / "r"))
    assert code == 2 and err == [f"error: --out: cannot create {tmp_path / 'f' / 'r'}: {tmp_path / 'f'} is a file, "
                                 "not a folder; choose another --out"]
    assert [p.name for p in tmp_path.iterdir()] == ["f"]


@pytest.mark.parametrize("args, message", [
    (["reproduce", "seed-000", "--quick", "--quiet", "--out", ""], "--out: is empty; give a folder path"),
    (["campaign", "run", "smoke", "--workers", "0", "--quiet", "--out", ""], "--out: is empty; give a folder path"),
    ([*QUICK_PERCEPTION, "--write-settings", ""], "--write-settings: is empty; give a file path, e.g. measured.toml"),
])
def test_an_empty_path_option_is_refused_not_read_as_the_default(capsys, tmp_path, monkeypatch, args, message):
    monkeypatch.chdir(tmp_path)
    code, _, err = _cli(capsys, *args)
    assert code == 2 and err == [f"error: {message}"]
    assert list(tmp_path.iterdir()) == []  # no runs/ folder


# --- output the terminal cannot encode -------------------------------------------------------------------------

def test_unencodable_output_is_escaped_not_an_internal_error(tmp_path):
    env = _env(tmp_path, PYTHONIOENCODING="ascii")
    proc = subprocess.run([sys.executable, "-m", "roadtrack.testbed.cli.main", "keys"], capture_output=True, cwd=REPO, env=env,
                          timeout=120)
    assert proc.returncode == 0 and proc.stderr == b"", proc.stderr[-300:]
    text = proc.stdout.decode("ascii")  # every byte ASCII
    assert "\\xa7" in text and text.count("\n") > 100
    proc = subprocess.run([sys.executable, "-m", "roadtrack.testbed.cli.main", "run", "conv\u00a7"], capture_output=True,
                          cwd=REPO, env=env, timeout=120)
    lines = proc.stderr.decode("ascii").strip().splitlines()
    assert proc.returncode == 2 and len(lines) == 1 and lines[0].startswith("error: conv\\xa7: no such scenario")


# --- strict JSON -----------------------------------------------------------------------------------------------

def test_json_text_writes_null_for_every_non_finite_number():
    doc = {"a": float("nan"), "b": [1.0, float("inf"), np.float32("nan"), (np.float64(-np.inf), 2)],
           "c": {"d": np.array([0.5, np.nan]), "e": np.int64(7), "f": np.bool_(True)}, np.int64(3): "k",
           float("nan"): 1, "g": None, "h": "NaN"}
    got = strict_json(json_text(doc, indent=1))
    assert got == {"a": None, "b": [1.0, None, None, [None, 2]], "c": {"d": [0.5, None], "e": 7, "f": True},
                   "3": "k", "nan": 1, "g": None, "h": "NaN"}
    assert finite(np.float64(2.5)) == 2.5 and type(finite(np.float64(2.5))) is float
    assert strict_json(json_text(Path("x"), default=str)) == "x"
    with pytest.raises(ValueError, match="bare NaN"):
        strict_json('{"x": NaN}')


def test_a_run_with_nothing_to_score_writes_null_not_nan(capsys, tmp_path):
    out = tmp_path / "run"
    code, _, err = _cli(capsys, "run", "convoy", "--set", "duration_s=0.1", "--no-record", *FAST, "--out", str(out))
    assert code == 0, err
    doc = strict_json_files(out)["scores.json"]
    scores = doc["scores"]
    assert scores["confirmed_tracks"] == 0 and doc["frames"] == 2  # 0.1 s: too short to confirm a track
    assert scores["track_precision_pct"] is None and scores["pos_rmse_m"] is None and scores["vel_rmse_mps"] is None
    assert scores["tp_pct"] == 0.0 and scores["cars_seen"] == 5
    assert all(isinstance(v, float) and math.isfinite(v) for v in doc["mot_metrics"].values())


def test_a_perception_report_is_strict_json(capsys, tmp_path):
    out = tmp_path / "report"
    code, _, err = _cli(capsys, "perception", "convoy", "--duration", "0.3", "--no-merge-sweep", *FAST,
                        "--out", str(out))
    assert code == 0, err
    doc = strict_json_files(out)["summary.json"]
    assert doc["summary"]["pd_occluded"] is None and doc["summary"]["frames"] == 4  # no car hidden in 0.3 s
    assert doc["summary"]["vehicle_frames"] == 20 and doc["summary"]["pd_visible"] == doc["summary"]["pd_in_range"]
    assert [row["occluded"] for row in doc["pd_by_range"]] == [None] * len(doc["pd_by_range"])
    assert set(doc["ablation"]) == {"full", "no map ROI", "no moving-object test", "neither", "thesis pipeline"}
    assert all(sc["track_precision_pct"] is None for sc in doc["ablation"].values())  # 4 frames: none confirmed


def test_a_campaign_folder_is_strict_json_and_resumes_and_reports(capsys, tmp_path):
    spec = tmp_path / "tiny.toml"
    spec.write_text('name = "tiny"\nscenarios = ["convoy"]\ntrackers = ["gnn-kf"]\nseeds = 1\n\n[overrides]\n'
                    'duration_s = 0.1\n"sensor.lidar.azimuth_step_deg" = 1.0\n\n[record]\nfull_seeds = [0]\n')
    out = tmp_path / "camp"
    code, _, err = _cli(capsys, "campaign", "run", str(spec), "--out", str(out), "--workers", "0", "--quiet")
    assert code == 0, err
    files = strict_json_files(out)
    assert {"meta.json", "scenarios.json"} <= set(files) and len(files) == 4
    (sensed,) = (v for k, v in files.items() if k.startswith("sensing/"))  # the sensing cache's entry
    assert sensed["frames"] == 2
    (recorded,) = (v for k, v in files.items() if k.startswith("recordings/") and k.endswith("/scores.json"))
    assert recorded["scores"]["track_precision_pct"] is None and recorded["frames"] == 2
    assert files["meta.json"]["name"] == "tiny" and files["meta.json"]["n_runs"] == 1
    for command in (["resume", str(out), "--workers", "0", "--quiet"], ["report", str(out)]):  # they read them
        code, _, err = _cli(capsys, "campaign", *command)
        assert code == 0, (command, err)


@pytest.mark.parametrize("option", ["--workers", "--threads", "--dask-local"])
def test_campaign_pool_sizes_are_bounded_before_any_work(capsys, tmp_path, option):
    code, _, err = _cli(capsys, "campaign", "run", "campaigns/clutter_sweep.toml", option, "100000",
                        "--out", str(tmp_path / "c"))
    assert code == 2 and len(err) == 1 and "expected at most 256, got 100000" in err[0], err
    assert not (tmp_path / "c").exists()


def test_committed_json_reports_are_strict():
    repo = Path(__file__).resolve().parent.parent
    files = sorted((repo / "docs").rglob("*.json"))
    assert files
    for path in files:
        strict_json(path.read_text())


def test_write_settings_through_a_symlink_is_refused_before_the_characterisation(capsys, tmp_path):
    victim = tmp_path / "victim.toml"
    victim.write_text("# someone's file\n")
    (tmp_path / "link.toml").symlink_to(victim)
    t0 = time.perf_counter()
    code, _, err = _cli(capsys, "perception", "convoy", "--write-settings", str(tmp_path / "link.toml"), "--quiet",
                        "--out", str(tmp_path / "rep"))
    assert code == 2 and len(err) == 1 and "is a symbolic link (to" in err[0], err
    assert time.perf_counter() - t0 < 5 and not (tmp_path / "rep").exists()
    assert victim.read_text() == "# someone's file\n"
