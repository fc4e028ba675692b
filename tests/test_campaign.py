"""Monte Carlo campaigns: strict campaign files, common random numbers, real runs on the local pool and on
Dask giving identical tables, a failing run recorded, resume after SIGKILL / Ctrl-C, the report.

Every campaign here is small real runs of cut_in_out shortened to 1 s. The test campaign has a grid value
that fails at run time but not at load time: JPDA with ``max_jpda_events = 1`` and
``jpda_overflow = "raise"`` raises JPDAOverflowError at its first multi-track cluster, which the wide gates
(``gate_alpha = 1e4``) make certain from frame 2 on (GNN ignores both keys).
"""
from __future__ import annotations

import argparse
import io
import math
import os
import signal
import subprocess
import sys
import time
import zlib
from contextlib import redirect_stderr, redirect_stdout
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from roadtrack.testbed.campaign import store
from roadtrack.testbed.cli.campaign import add_campaign_parser, main as campaign_main
from roadtrack.testbed.campaign.engine import EngineOptions, run_campaign
from roadtrack.testbed.campaign.report import fmt_ci, mean_sd_ci, paired_differences, write_report
from roadtrack.testbed.campaign.spec import load_campaign, plan, run_seed
from roadtrack.testbed.common.threads import DEFAULTED, THREAD_VARS
from roadtrack.testbed.config.strict import ConfigError

REPO = Path(__file__).resolve().parent.parent
ENV = dict(os.environ, RERUN_ANALYTICS="0")

CAMPAIGN = """\
name = "t"
scenarios = ["cut_in_out"]
trackers = ["jpda-kf", "gnn-kf"]
seeds = 2
base_seed = 11

[overrides]
duration_s = 1.0
tracker.associator.method = "enumerate"  # the exhaustive enumeration, with its event cap
tracker.associator.on_overflow = "raise"
tracker.associator.gate_alpha = 1e4  # wide gates: every track in one cluster from frame 2 on

[grid]
"tracker.associator.max_events" = [50000, 1]
"""
N_RUNS = 8


def _write(tmp_path: Path, text: str, name: str = "c.toml") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def _cli(*argv: str) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with redirect_stdout(out), redirect_stderr(err):
        code = campaign_main(list(argv))
    return code, out.getvalue(), err.getvalue()


def _comparable(df: pd.DataFrame) -> pd.DataFrame:
    df = df.drop(columns=store.timing_columns(df.columns))
    return df[sorted(df.columns)].sort_values("run_id").reset_index(drop=True)


def assert_same_results(a: pd.DataFrame, b: pd.DataFrame) -> None:
    """Same rows (run ids) and bit-identical values in every column except timing / wall-time ones."""
    a, b = _comparable(a), _comparable(b)
    assert list(a.columns) == list(b.columns)
    assert list(a["run_id"]) == list(b["run_id"])
    for col in a.columns:
        if col == store.SERIES_COLUMN:
            for x, y in zip(a[col], b[col]):
                np.testing.assert_array_equal(np.asarray(x, float), np.asarray(y, float))
        else:
            pd.testing.assert_series_equal(a[col], b[col], check_exact=True, obj=col)


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """The test campaign, uninterrupted, on a 2-worker local pool."""
    tmp = tmp_path_factory.mktemp("reference")
    path = _write(tmp, CAMPAIGN)
    campaign = load_campaign(path)
    out = tmp / "out"
    store.create(out, path, campaign)
    outcome = run_campaign(campaign, out, EngineOptions(workers=2), quiet=True)
    assert outcome.complete and outcome.ran == N_RUNS and not outcome.interrupted
    return out, pd.read_parquet(out / store.RESULTS_FILE)


def test_each_traffic_is_sensed_once_and_every_run_equals_one_without_the_cache(reference, tmp_path):
    """Sense once, track many (issue 18): 8 runs, 2 seeds, one sensing-cache entry per seed (the grid key and
    the trackers do not change sensing); the same results as every run sensing its own traffic (run here in this
    process: the pool is the reference's)."""
    out, ref = reference
    entries = [p for p in (out / store.SENSING_DIR).iterdir() if not p.name.startswith(".")]
    assert len(entries) == 2 and all((p / "meta.json").is_file() for p in entries)
    path = _write(tmp_path, CAMPAIGN)
    campaign = load_campaign(path)
    store.create(tmp_path / "plain", path, campaign)
    outcome = run_campaign(campaign, tmp_path / "plain", EngineOptions(workers=0, sensing_cache=False), quiet=True)
    assert outcome.complete and not (tmp_path / "plain" / store.SENSING_DIR).exists()
    assert_same_results(pd.read_parquet(tmp_path / "plain" / store.RESULTS_FILE), ref)


# ---------------------------------------------------------------------------------------- campaign files


def test_shipped_campaigns_load():
    sweep = load_campaign("clutter_sweep")
    assert sweep.trackers == ("jpda-kf", "pda-kf", "gnn-kf") and sweep.seeds == 20
    assert sweep.grid_keys == ("sensor.clutter.density_per_m2",) and len(sweep.grid[0][1]) == 3
    assert sweep.n_runs == len(plan(sweep)) == 180
    smoke = load_campaign(REPO / "campaigns" / "smoke.toml")
    assert smoke.n_runs == len(plan(smoke)) == 8


def test_bare_and_quoted_dotted_keys_mean_the_same(tmp_path):
    bare = load_campaign(_write(tmp_path, CAMPAIGN, "a.toml"))
    quoted = load_campaign(_write(tmp_path, CAMPAIGN.replace('tracker.associator.on_overflow',
                                                             '"tracker.associator.on_overflow"'), "b.toml"))
    assert bare.overrides == quoted.overrides == {"duration_s": 1.0, "tracker.associator.method": "enumerate",
                                                  "tracker.associator.on_overflow": "raise",
                                                  "tracker.associator.gate_alpha": 1e4}
    assert bare.grid == (("tracker.associator.max_events", (50000, 1)),)


BASE = 'scenarios = ["cut_in_out"]\ntrackers = ["jpda-kf"]\nseeds = 2\n'


@pytest.mark.parametrize("text, message", [
    (BASE + "bogus = 1\n", "bogus: unknown key; allowed: base_seed, baseline, description, grid, name, overrides, record, "),
    (BASE + 'baseline = "pda-kf"\n', "baseline: 'pda-kf' is not one of the campaign's trackers (jpda-kf)"),
    (BASE.replace("seeds = 2", 'seeds = "2"'), "seeds: expected an integer, got '2'"),
    (BASE.replace("seeds = 2", "seeds = 0"), "seeds: 0 is not allowed; must be > 0"),
    (BASE + "[grid]\nsensor.clutter.densty = [1.0]\n",
     'grid."sensor.clutter.densty"[0]: sensor.clutter.densty: unknown key; allowed: density_per_m2, radius_m'),
    (BASE + "[grid]\nsensor.clutter.density_per_m2 = [0.0, 0.1, -1.0]\n",
     'grid."sensor.clutter.density_per_m2"[2]: sensor.clutter.density_per_m2: -1.0 is not allowed; must be >= 0'),
    (BASE + '[grid]\n"sensor.clutter.density_per_m2" = [0.0, "x"]\n',
     'grid."sensor.clutter.density_per_m2"[1]: sensor.clutter.density_per_m2: expected a number, got \'x\''),
    (BASE + '[grid]\n"sensor.clutter.density_per_m2" = []\n',
     'grid."sensor.clutter.density_per_m2": empty list; give at least one value'),
    (BASE + "[grid]\nduration_s = 3.0\n", 'grid."duration_s": expected a list of values, got 3.0'),
    (BASE + "[grid]\nconvoy.gap_m = [2.0, 5.0]\n", 'grid."convoy.gap_m": convoy is not set in this scenario'),
    (BASE + "[grid]\nvehicles.7.speed_mps = [20.0]\n", "grid.\"vehicles.7.speed_mps\": vehicles.7: no item '7'"),
    (BASE + "[grid]\ntracker.filter.sigma_q = [1.0]\n",
     'grid."tracker.filter.sigma_q": no tracker of this campaign has filter parameter \'sigma_q\'; allowed: detection_R, motion, '),
    (BASE + "[grid]\ntracker.filter.sigma_v = [-1.0]\n",
     'grid."tracker.filter.sigma_v"[0]: tracker.filter.sigma_v: -1.0 is not allowed; must be >= 0'),
    (BASE + "[overrides]\nduration_s = -5.0\n", 'overrides."duration_s": duration_s: -5.0 is not allowed; must be > 0'),
    (BASE + "[overrides]\nseed = 3\n", 'overrides."seed": cannot be set by a campaign'),
    (BASE + '[grid]\n"tracker.name" = ["gnn-kf"]\n', 'grid."tracker.name": cannot be set by a campaign'),
    (BASE + '[overrides]\ntracker.filter.sigma_v = 1.0\n[grid]\n"tracker.filter" = [{sigma_v = 2.0}]\n',
     'grid."tracker.filter": overlaps overrides."tracker.filter.sigma_v"'),
    (BASE.replace('"jpda-kf"', '"jpda-kf", "jpda-ukf"'), "trackers[1]: unknown tracker name 'jpda-ukf'"),
    (BASE.replace('"jpda-kf"', '"jpda-kf", "jpda-kf"'), "trackers[1]: tracker 'jpda-kf' appears twice"),
    (BASE.replace('"cut_in_out"', '"cut_in_out", "nowhere"'), "scenarios[1]: nowhere: no such scenario file"),
    (BASE.replace('["cut_in_out"]', "[]"), "scenarios: () is not allowed; must be a non-empty list"),
    (BASE + "[record]\nfull_seeds = [2]\n", "record.full_seeds[0]: 2 is not a seed index; allowed: 0..1"),
    (BASE + "[record]\nfull = true\n", "record.full: unknown key; allowed: full_seeds"),
    (BASE + "[grid\n", "not valid TOML"),
])
def test_malformed_campaign_is_rejected_with_one_line_naming_the_key(tmp_path, text, message):
    path = _write(tmp_path, text)
    with pytest.raises(ConfigError) as info:
        load_campaign(path)
    text = str(info.value)
    assert "\n" not in text
    assert text.startswith(f"{path}: "), text
    assert message in text, text


def test_malformed_campaign_cli_exit_2_and_nothing_written(tmp_path):
    path = _write(tmp_path, BASE + "[grid]\nsensor.clutter.density_per_m2 = [-1.0]\n")
    out = tmp_path / "out"
    code, stdout, stderr = _cli("run", str(path), "--out", str(out), "--quiet")
    assert code == 2
    assert stderr.startswith("error: ") and stderr.count("\n") == 1, stderr
    assert 'grid."sensor.clutter.density_per_m2"[0]' in stderr
    assert not out.exists()
    code, _, stderr = _cli("resume", str(tmp_path))
    assert code == 2 and "not a campaign directory" in stderr


def test_results_dir_keeps_the_scenarios_it_started_with(tmp_path):
    (tmp_path / "scn").mkdir()
    scn = tmp_path / "scn" / "my_road.toml"
    scn.write_text((REPO / "scenarios" / "cut_in_out.toml").read_text().replace('name = "cut_in_out"',
                                                                                  'name = "my_road"'))
    path = _write(tmp_path, BASE.replace('"cut_in_out"', '"scn/my_road.toml"'), "sweep_a.toml")
    campaign = load_campaign(path)
    assert campaign.name == "sweep_a" and campaign.scenarios[0].name == "my_road"
    out = tmp_path / "out"
    store.create(out, path, campaign)
    assert (out / store.CAMPAIGN_FILE).read_bytes() == path.read_bytes()
    scn.unlink()  # the original files may change or go: a resumed campaign runs what it started with
    path.unlink()
    again = store.open_campaign(out)
    assert again.name == "sweep_a" and again.scenarios == campaign.scenarios
    assert [r.run_id for r in plan(again)] == [r.run_id for r in plan(campaign)]
    assert [r.seed for r in plan(again)] == [r.seed for r in plan(campaign)]
    with pytest.raises(ConfigError, match="already holds a campaign"):
        store.create(out, out / store.CAMPAIGN_FILE, campaign)


def test_seeds_are_common_random_numbers(tmp_path):
    campaign = load_campaign(_write(tmp_path, CAMPAIGN))
    runs = plan(campaign)
    assert len(runs) == N_RUNS == len({r.run_id for r in runs})
    for r in runs:
        want = np.random.SeedSequence([11, zlib.crc32(b"cut_in_out"), r.seed_index]).generate_state(1)[0]
        assert r.seed == int(want) == run_seed(11, "cut_in_out", r.seed_index)
    by_index = {}
    for r in runs:  # same seed for every tracker and grid value, different seeds for different indices
        by_index.setdefault(r.seed_index, set()).add(r.seed)
    assert all(len(s) == 1 for s in by_index.values()) and len(set().union(*by_index.values())) == 2


# ---------------------------------------------------------------------------------------- real runs


def test_failing_run_is_recorded_and_the_others_finish(reference):
    _, df = reference
    assert len(df) == N_RUNS and list(df["run_index"]) == list(range(N_RUNS))
    bad = df[(df["tracker"] == "jpda-kf") & (df["tracker.associator.max_events"] == 1)]
    assert len(bad) == 2 and set(bad["status"]) == {"error"}
    assert set(bad["error_type"]) == {"JPDAOverflowError"}
    assert all("max_events=1" in e and "\n" not in e for e in bad["error"])
    assert all(w.startswith("jpda.py:") for w in bad["error_where"])
    assert bad["tp_pct"].isna().all()
    good = df.drop(bad.index)
    assert set(good["status"]) == {"ok"} and (good["error"] == "").all()
    assert np.isfinite(good["tp_pct"]).all() and (good["n_frames"] == 11).all()
    assert all(len(s) == 11 for s in good[store.SERIES_COLUMN])
    for col in ("v_roadtrack", "v_numpy", "v_highway_env", "v_open3d", "v_rerun", "wall_s", "scenario", "seed"):
        assert col in df.columns


def test_same_seed_gives_same_traffic_whatever_the_parameter(reference):
    # GNN ignores max_jpda_events: with common random numbers its two grid points are the same runs
    _, df = reference
    gnn = df[df["tracker"] == "gnn-kf"].set_index(["seed_index", "tracker.associator.max_events"])
    for k in (0, 1):
        a, b = gnn.loc[(k, 50000)], gnn.loc[(k, 1)]
        for col in ("tp_pct", "fp_pct", "pos_rmse_m", "vel_rmse_mps", "n_matched_frames"):
            assert a[col] == b[col] or (math.isnan(a[col]) and math.isnan(b[col])), col
        np.testing.assert_array_equal(a[store.SERIES_COLUMN], b[store.SERIES_COLUMN])


def test_dask_local_cluster_gives_the_same_results_as_the_pool(reference, tmp_path, monkeypatch):
    ref_dir, ref = reference
    for var in (*THREAD_VARS, DEFAULTED):  # unset, as for a Python API user: conftest's 1s would hide a leaked nanny 1
        monkeypatch.delenv(var, raising=False)
    campaign = store.open_campaign(ref_dir)
    out = tmp_path / "dask"
    store.create(out, ref_dir / store.CAMPAIGN_FILE, campaign)
    env = {k: os.environ.get(k) for k in ("MALLOC_TRIM_THRESHOLD_", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS")}
    outcome = run_campaign(campaign, out, EngineOptions(dask_local=2), quiet=True)
    assert outcome.complete and outcome.failed == 2
    # Dask's nanny writes its worker variables into this process: they must not leak into later pools
    assert {k: os.environ.get(k) for k in env} == env
    assert_same_results(pd.read_parquet(out / store.RESULTS_FILE), ref)


def _start(tmp_path: Path, *args: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "roadtrack.testbed.cli.campaign", *args], cwd=REPO, env=ENV,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)


def _wait_for_runs(out: Path, n: int, proc: subprocess.Popen, timeout: float = 120.0) -> int:
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        done = len(list((out / store.RUNS_DIR).glob("*.parquet"))) if (out / store.RUNS_DIR).is_dir() else 0
        if done >= n:
            return done
        assert proc.poll() is None, proc.communicate()
        time.sleep(0.02)
    raise AssertionError(f"no {n} finished runs after {timeout} s")


def test_resume_after_sigkill_gives_exactly_the_uninterrupted_rows(reference, tmp_path):
    _, ref = reference
    path = _write(tmp_path, CAMPAIGN)
    out = tmp_path / "killed"
    proc = _start(tmp_path, "run", str(path), "--out", str(out), "--workers", "1", "--quiet")
    _wait_for_runs(out, 3, proc)
    os.killpg(proc.pid, signal.SIGKILL)  # the campaign and its workers, like a power cut
    proc.wait(timeout=30)
    before = {p.stem: p.stat().st_mtime_ns for p in (out / store.RUNS_DIR).glob("*.parquet")}
    assert 3 <= len(before) < N_RUNS, "killed too late to test resuming"

    code, stdout, stderr = _cli("resume", str(out), "--workers", "2", "--quiet")
    assert code == 0, stderr
    assert f"{N_RUNS} runs (2 failed" in stdout
    after = {p.stem: p.stat().st_mtime_ns for p in (out / store.RUNS_DIR).glob("*.parquet")}
    assert len(after) == N_RUNS
    assert all(after[k] == v for k, v in before.items()), "a finished run was run again"
    assert not [p for p in (out / store.RUNS_DIR).iterdir() if p.name.startswith(".")]
    assert_same_results(pd.read_parquet(out / store.RESULTS_FILE), ref)

    code, stdout, _ = _cli("resume", str(out), "--quiet")  # nothing left to do
    assert code == 0 and "0 run now" in stdout


def _children(pid: int) -> list[int]:
    """Live (not zombie) processes whose parent is ``pid``."""
    out = []
    for status in Path("/proc").glob("[0-9]*/status"):
        try:
            fields = dict(line.split(":\t", 1) for line in status.read_text().splitlines() if ":\t" in line)
        except OSError:
            continue
        if fields.get("PPid", "").strip() == str(pid) and not fields.get("State", "").startswith("Z"):
            out.append(int(status.parent.name))
    return out


def _alive(pid: int) -> bool:
    try:
        return not Path(f"/proc/{pid}/status").read_text().split("State:\t", 1)[1].startswith("Z")
    except (OSError, IndexError):
        return False


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="PR_SET_PDEATHSIG is Linux-only")
def test_workers_die_with_a_sigkilled_campaign(tmp_path):
    """kill -9 of the campaign process alone (not its process group): its pool workers follow within 10 s."""
    path = _write(tmp_path, CAMPAIGN)
    out = tmp_path / "orphans"
    proc = _start(tmp_path, "run", str(path), "--out", str(out), "--workers", "2", "--quiet")
    _wait_for_runs(out, 1, proc)
    workers = [c for c in _children(proc.pid) if "spawn_main" in Path(f"/proc/{c}/cmdline").read_text()]
    assert len(workers) == 2, workers
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait(timeout=30)
    t0 = time.monotonic()
    while any(_alive(w) for w in workers) and time.monotonic() - t0 < 10.0:
        time.sleep(0.1)
    assert not any(_alive(w) for w in workers), [w for w in workers if _alive(w)]


def test_ctrl_c_keeps_finished_runs_and_exits_130(tmp_path):
    path = _write(tmp_path, CAMPAIGN)
    out = tmp_path / "stopped"
    proc = _start(tmp_path, "run", str(path), "--out", str(out), "--workers", "1")
    _wait_for_runs(out, 2, proc)
    os.killpg(proc.pid, signal.SIGINT)  # what a terminal's Ctrl-C does
    _, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 130, stderr
    assert f"resume with: testbed campaign resume {out}" in stderr
    kept = sorted(p.stem for p in (out / store.RUNS_DIR).glob("*.parquet"))
    assert 2 <= len(kept) < N_RUNS
    assert sorted(pd.read_parquet(out / store.RESULTS_FILE)["run_id"]) == kept


def _worker_pids(parent: int) -> list[int]:
    """Pids of the process-pool workers among the children of ``parent`` (not the resource tracker)."""
    out = []
    for tid in os.listdir(f"/proc/{parent}/task"):
        for child in Path(f"/proc/{parent}/task/{tid}/children").read_text().split():
            try:
                cmd = Path(f"/proc/{child}/cmdline").read_bytes()
            except OSError:
                continue
            if b"spawn_main" in cmd:
                out.append(int(child))
    return out


def test_killed_worker_stops_the_campaign_and_resume_finishes_it(reference, tmp_path):
    _, ref = reference
    path = _write(tmp_path, CAMPAIGN)
    out = tmp_path / "worker-killed"
    proc = _start(tmp_path, "run", str(path), "--out", str(out), "--workers", "1", "--quiet")
    _wait_for_runs(out, 2, proc)
    workers = _worker_pids(proc.pid)
    assert len(workers) == 1
    os.kill(workers[0], signal.SIGKILL)
    _, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 1, stderr
    assert "error: a worker process died" in stderr and f"resume with: testbed campaign resume {out}" in stderr
    kept = len(list((out / store.RUNS_DIR).glob("*.parquet")))
    assert 2 <= kept < N_RUNS
    code, _, stderr = _cli("resume", str(out), "--workers", "2", "--quiet")
    assert code == 0, stderr
    assert_same_results(pd.read_parquet(out / store.RESULTS_FILE), ref)


def test_full_recording_of_chosen_seeds(tmp_path):
    text = CAMPAIGN.replace('trackers = ["jpda-kf", "gnn-kf"]', 'trackers = ["gnn-kf"]').replace(
        '"tracker.associator.max_events" = [50000, 1]', "") + "[record]\nfull_seeds = [1]\n"
    text = "\n".join(line for line in text.splitlines()  # JPDA-only keys: no tracker of this campaign has them
                     if not line.startswith(("tracker.associator.method", "tracker.associator.on_overflow"))) + "\n"
    campaign = load_campaign(_write(tmp_path, text))
    out = tmp_path / "rec"
    store.create(out, tmp_path / "c.toml", campaign)
    assert run_campaign(campaign, out, EngineOptions(workers=0), quiet=True).complete
    df = pd.read_parquet(out / store.RESULTS_FILE)
    assert list(df["recorded"]) == [False, True]
    rec = store.recording_dir(out, df["run_id"][1])
    for name in ("run.rrd", "truth.parquet", "detections.parquet", "tracks.parquet", "scores.json"):
        assert (rec / name).is_file(), name
    assert not store.recording_dir(out, df["run_id"][0]).exists()
    rep = write_report(out, campaign)  # a campaign without a grid: scores by tracker
    assert rep.n_runs == 2 and sorted(p.name for p in rep.plots) == ["rmse_vs_time.png", "scores_by_tracker.png"]


def test_report_tables_and_plots(reference):
    out, df = reference
    parser = argparse.ArgumentParser(prog="testbed")
    add_campaign_parser(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(["campaign", "report", str(out)])
    buf = io.StringIO()
    with redirect_stdout(buf):
        assert args.func(args) == 0
    assert f"wrote {out / 'report.md'}" in buf.getvalue()
    md = (out / "report.md").read_text()
    # opens with one summary table (n per cell), then warnings, paired differences, the thesis rows once
    heads = [line for line in md.splitlines() if line.startswith("## ")]
    assert heads[:4] == ["## Summary", "## Warnings", "## Paired differences against `jpda-kf`",
                         "## The thesis's published rows (for orientation)"], heads
    assert "| scenario | tracker | `tracker.associator.max_events` | n | TP [%] |" in md
    assert "**n < 5** in 4 of 4 cells" in md
    assert md.count("thesis Table 4.3: JPDA-KF") == 1
    assert "| tracker | `tracker.associator.max_events` | score | runs | failed | n | sd | mean [95 % CI] |" in md
    assert md.count("\n|---") <= 6  # summary, paired, thesis rows, thesis form, details, failed runs
    assert "## Failed runs" in md and "JPDAOverflowError" in md
    pngs = sorted(p.name for p in (out / "plots").glob("*.png"))
    assert pngs == ["paired_vs_jpda-kf.png", "rmse_vs_time.png", "scores_vs_tracker.associator.max_events.png"]
    for p in pngs:
        assert (out / "plots" / p).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        assert f"](plots/{p})" in md
    summary = pd.read_csv(out / "summary.csv")
    cell = summary[(summary["tracker"] == "gnn-kf") & (summary["tracker.associator.max_events"] == 50000)
                   & (summary["score"] == "pos_rmse_m")].iloc[0]
    values = df[(df["tracker"] == "gnn-kf") & (df["tracker.associator.max_events"] == 50000)]["pos_rmse_m"]
    assert cell["n"] == 2 and cell["runs"] == 2 and cell["failed"] == 0
    assert cell["mean"] == pytest.approx(values.mean(), rel=1e-12)
    assert cell["sd"] == pytest.approx(values.std(ddof=1), rel=1e-12)
    half = 12.706204736174698 * values.std(ddof=1) / math.sqrt(2)  # t_{0.975, 1}
    assert cell["ci_hi"] - cell["mean"] == pytest.approx(half, rel=1e-9)
    failed = summary[(summary["tracker"] == "jpda-kf") & (summary["tracker.associator.max_events"] == 1)]
    assert (failed["n"] == 0).all() and (failed["failed"] == 2).all()
    # thesis-table form: counts summed over the ok runs, percentages of the sums, thesis rows beside
    ok = df[(df["tracker"] == "gnn-kf") & (df["tracker.associator.max_events"] == 50000)]
    seen, tracked, false = (int(ok[c].sum()) for c in ("cars_seen", "cars_tracked", "false_tracks"))
    row = f"| gnn-kf (ours) | 50000 | 2 | {seen} | {tracked} | {false} | {100 * tracked / seen:.4g} |"
    assert "### Thesis-table form" in md and row in md
    assert "| thesis Table 4.3: JPDA-KF | 58 | 49 | 9 | 84.48 | 15.52 | 8 |" in md
    assert "| thesis Table 5.4: JPDA-GVBL-SVSF (text: APDA-SVSF) | – | – | – | 93.42 | 6.58 | 3.1 |" in md
    # paired by seed: gnn-kf minus jpda-kf at max_events 50000, by hand
    g = df[(df["tracker.associator.max_events"] == 50000)].set_index(["tracker", "seed_index"])["pos_rmse_m"]
    d = (g["gnn-kf"] - g["jpda-kf"]).to_numpy()
    n, mean, _, lo, hi = mean_sd_ci(d)
    section = md.split("## Paired differences")[1].split("\n## ")[0]
    paired = next(line for line in section.splitlines() if line.startswith("| cut_in_out | gnn-kf | 50000 | 2 | "))
    assert f"| {fmt_ci(mean, lo, hi)} |" in paired and n == 2


def test_intervals_print_with_matching_precision():
    assert fmt_ci(77.8712, 75.123, 80.619) == "77.9 [75.1, 80.6]"  # half-width 2.7: one decimal
    assert fmt_ci(0.19083, 0.1664, 0.2153) == "0.191 [0.166, 0.215]"
    assert fmt_ci(100.0, 100.0, 100.0) == "100 (no spread)"  # never "100 ± 0" or "[77.87, 77.87]"
    assert fmt_ci(3.5, math.nan, math.nan) == "3.5" and fmt_ci(math.nan, 1, 2) == "–"


def test_paired_differences_pair_by_seed_and_warnings_flag_identical_seeds():
    from roadtrack.testbed.campaign.report import _warnings, summarize

    rows = []
    for seed in range(4):
        for tracker, bias in (("jpda-kf", 0.0), ("pda-kf", 1.0)):
            rows.append(dict(scenario="s", tracker=tracker, seed_index=seed, status="ok", tp_pct=50.0 + 10 * seed + bias,
                             cars_seen=10, cars_tracked=5, false_tracks=1, cars_relabelled=0))
            rows.append(dict(scenario="same", tracker=tracker, seed_index=seed, status="ok", tp_pct=80.0,
                             cars_seen=4, cars_tracked=3, false_tracks=0, cars_relabelled=0))
    df = pd.DataFrame(rows)
    pairs = paired_differences(df, "jpda-kf", [], ["tp_pct"])
    r = pairs[pairs["scenario"] == "s"].iloc[0]
    assert (r["tracker"], r["n"], r["mean"]) == ("pda-kf", 4, 1.0)  # the seeds' spread of 30 points cancels
    assert r["ci_lo"] == pytest.approx(1.0) and r["ci_hi"] == pytest.approx(1.0)
    text = "\n".join(_warnings(df, summarize(df, []), [], ["tp_pct"]))
    assert "**n < 5** in 4 of 4 cells" in text and "**Seeds gave identical results** in 2 cells (scenarios: same)" in text


def test_mean_sd_ci_student_t():
    n, mean, sd, lo, hi = mean_sd_ci([1.0, 2.0, 3.0, 4.0, np.nan])
    assert n == 4 and mean == 2.5 and sd == pytest.approx(math.sqrt(5 / 3), rel=1e-12)
    half = 3.182446305284263 * math.sqrt(5 / 3) / 2  # t_{0.975, 3}
    assert (lo, hi) == (pytest.approx(2.5 - half, rel=1e-12), pytest.approx(2.5 + half, rel=1e-12))
    assert mean_sd_ci([7.0])[:2] == (1, 7.0) and math.isnan(mean_sd_ci([7.0])[3])
    assert mean_sd_ci([])[0] == 0


def test_run_refuses_an_existing_campaign_dir(reference):
    out, _ = reference
    code, _, stderr = _cli("run", str(out / store.CAMPAIGN_FILE), "--out", str(out))
    assert code == 2 and "already holds a campaign" in stderr and "testbed campaign resume" in stderr


@pytest.mark.slow
def test_smoke_campaign_killed_on_dask_resumed_on_the_pool(tmp_path):
    """The shipped smoke campaign (with full recordings of seed 0) through the CLI: killed while running
    on a Dask LocalCluster, resumed on the local pool, equal to an uninterrupted local-pool campaign."""
    ref_out = tmp_path / "ref"
    code, _, stderr = _cli("run", "smoke", "--out", str(ref_out), "--workers", "2", "--quiet")
    assert code == 0, stderr
    out = tmp_path / "killed"
    proc = _start(tmp_path, "run", "smoke", "--out", str(out), "--dask-local", "2", "--quiet")
    _wait_for_runs(out, 3, proc, timeout=180)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait(timeout=30)
    assert len(list((out / store.RUNS_DIR).glob("*.parquet"))) < 8
    code, _, stderr = _cli("resume", str(out), "--workers", "2", "--quiet")
    assert code == 0, stderr
    assert_same_results(pd.read_parquet(out / store.RESULTS_FILE), pd.read_parquet(ref_out / store.RESULTS_FILE))
    assert len(list((out / store.RECORDINGS_DIR).glob("*/run.rrd"))) == 4


def test_threads_zero_is_refused_not_ignored(tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        campaign_main(["run", "campaigns/smoke.toml", "--threads", "0", "--out", str(tmp_path / "c")])
    assert exc.value.code == 2
    assert "argument --threads: expected an integer >= 1, got 0" in capsys.readouterr().err
    assert not (tmp_path / "c").exists()


def test_confidence_intervals_are_clipped_to_each_scores_range():
    import pandas as pd

    from roadtrack.testbed.campaign.report import summarize

    df = pd.DataFrame(dict(scenario="s", tracker="t", status="ok", tp_pct=[100.0, 100.0, 40.0],
                           fp_pct=[0.0, 0.0, 300.0], hota=[0.99, 0.2, 0.99]))
    rows = summarize(df, []).set_index("score")
    assert rows.loc["tp_pct", "ci_hi"] == 100.0 and rows.loc["tp_pct", "ci_lo"] < 100.0
    assert rows.loc["fp_pct", "ci_lo"] == 0.0 and rows.loc["fp_pct", "ci_hi"] > 100.0  # FP % may pass 100
    assert rows.loc["hota", "ci_hi"] == 1.0 and rows.loc["hota", "ci_lo"] == 0.0
    raw = mean_sd_ci(np.array([100.0, 100.0, 40.0]))
    assert raw[4] > 100.0  # without the clip the interval would pass 100 %
