"""Campaign hardening (issue 9): a damaged campaign folder, a bad or unreachable ``--scheduler`` and a
folder in use by another process each give one line and exit code 2 (input) or 1 (run time); a damaged
run file is run again (resume) or left out (report) with a warning line; report is safe beside a running
campaign. The fault test (SIGKILL of the parent, no orphan) is tests/test_faults.py.
"""
from __future__ import annotations

import io
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from contextlib import redirect_stderr, redirect_stdout
from pathlib import Path

import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from roadtrack.testbed.campaign import store
from roadtrack.testbed.cli.campaign import main as campaign_main
from roadtrack.testbed.campaign.engine import EngineOptions, run_campaign
from roadtrack.testbed.campaign.spec import load_campaign
from roadtrack.testbed.config.strict import ConfigError

REPO = Path(__file__).resolve().parent.parent
CAMPAIGN = """\
name = "hard"
scenarios = ["cut_in_out"]
trackers = ["gnn-kf"]
seeds = 2

[overrides]
duration_s = 0.5
"""
RUN_IDS = ["cut_in_out--gnn-kf--s000", "cut_in_out--gnn-kf--s001"]


def _cli(*argv: str) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with redirect_stdout(out), redirect_stderr(err):
        code = campaign_main(list(argv))
    return code, out.getvalue(), err.getvalue()


def _one_error_line(stderr: str) -> str:
    assert stderr.startswith("error: ") and stderr.count("\n") == 1, stderr
    assert "Traceback" not in stderr
    return stderr[len("error: "):].rstrip("\n")


@pytest.fixture(scope="module")
def finished(tmp_path_factory) -> Path:
    """A complete two-run campaign folder (real runs, in this process)."""
    tmp = tmp_path_factory.mktemp("hard")
    path = tmp / "hard.toml"
    path.write_text(CAMPAIGN)
    campaign = load_campaign(path)
    out = tmp / "done"
    store.create(out, path, campaign)
    assert run_campaign(campaign, out, EngineOptions(workers=0), quiet=True).complete
    return out


@pytest.fixture
def folder(finished, tmp_path) -> Path:
    """A fresh copy of the finished campaign folder, to damage."""
    return Path(shutil.copytree(finished, tmp_path / "c"))


# ---------------------------------------------------------------------------------- damaged folder files


def _damage(path: Path, kind: str) -> None:
    good = path.read_bytes()
    if kind == "empty":
        path.write_bytes(b"")
    elif kind == "truncated":
        path.write_bytes(good[: len(good) // 2])
    elif kind == "binary":
        path.write_bytes(b"\xff\xfe\x00\x01" * 8)
    elif kind == "missing":
        path.unlink()
    elif kind == "directory":  # unreadable as a file (permissions do not stop root, which CI is)
        path.unlink()
        path.mkdir()


DAMAGE = {"empty": "empty", "truncated": "not valid", "binary": "not UTF-8 text", "missing": "missing",
          "directory": "cannot be read"}


@pytest.mark.parametrize("name", [store.META_FILE, store.SCENARIOS_FILE, store.CAMPAIGN_FILE])
@pytest.mark.parametrize("kind", list(DAMAGE))
def test_damaged_folder_file_is_one_line_exit_2(folder, name, kind):
    _damage(folder / name, kind)
    before = sorted(p.name for p in (folder / store.RUNS_DIR).iterdir())
    for command in (["report", str(folder)], ["resume", str(folder), "--workers", "0", "--quiet"]):
        code, stdout, stderr = _cli(*command)
        line = _one_error_line(stderr)
        assert code == 2, stderr
        if name == store.CAMPAIGN_FILE and kind == "missing":  # campaign.toml is what makes a campaign folder
            assert line.startswith(f"{folder}: not a campaign directory (no {name})"), line
        else:
            assert line.startswith(f"{folder / name}: ") and DAMAGE[kind] in line, line
    assert sorted(p.name for p in (folder / store.RUNS_DIR).iterdir()) == before  # nothing ran or moved


def _edit_json(path: Path, edit) -> None:
    data = json.loads(path.read_text())
    path.write_text(json.dumps(edit(data)))


@pytest.mark.parametrize("name, edit, message", [
    (store.META_FILE, lambda d: [d], "expected a JSON object (the campaign name, source and versions), got list"),
    (store.META_FILE, lambda d: {**d, "name": 5}, "meta.json: name: expected a string, got 5"),
    (store.SCENARIOS_FILE, lambda d: {}, "has no scenario 'cut_in_out'"),
    (store.SCENARIOS_FILE, lambda d: {"cut_in_out": [1]}, "cut_in_out: expected a scenario (a JSON object), got list"),
    (store.SCENARIOS_FILE, lambda d: {"cut_in_out": {**d["cut_in_out"], "duration_s": "x"}},
     "cut_in_out: duration_s: expected a number, got 'x'"),
    (store.SCENARIOS_FILE, lambda d: {"cut_in_out": {**d["cut_in_out"], "vehicles": 5}}, "cut_in_out: vehicles: "),
])
def test_wrong_types_in_folder_json_name_the_file_and_key(folder, name, edit, message):
    _edit_json(folder / name, edit)
    code, _, stderr = _cli("report", str(folder))
    line = _one_error_line(stderr)
    assert code == 2 and line.startswith(str(folder / name)) and message in line, line


def test_wrong_types_in_stored_campaign_file(folder):
    path = folder / store.CAMPAIGN_FILE
    path.write_text(path.read_text().replace("seeds = 2", 'seeds = "2"'))
    code, _, stderr = _cli("resume", str(folder), "--workers", "0")
    assert code == 2 and _one_error_line(stderr) == f"{path}: seeds: expected an integer, got '2'"


def test_not_a_campaign_folder(tmp_path):
    for target, message in ((tmp_path / "nowhere", "no such campaign folder"), (tmp_path, "not a campaign directory")):
        code, _, stderr = _cli("report", str(target))
        assert code == 2 and message in _one_error_line(stderr)


# ---------------------------------------------------------------------------------- damaged run files


def _break_runs(folder: Path) -> dict[str, str]:
    """Damage run s001 (truncated) and add a stale temp file; return what the warnings must name."""
    run = store.run_path(folder, RUN_IDS[1])
    run.write_bytes(run.read_bytes()[:300])
    (folder / store.RUNS_DIR / f".{run.name}.tmp-999999").write_bytes(b"half")
    return {"run": str(run), "why": "not a readable parquet file"}


def test_report_leaves_a_damaged_run_out_and_removes_nothing(folder):
    want = _break_runs(folder)
    listing = sorted(p.name for p in (folder / store.RUNS_DIR).iterdir())
    code, stdout, stderr = _cli("report", str(folder))
    assert code == 0, stderr
    assert stderr.count("\n") == 1 and stderr.startswith(f"warning: {want['run']}: {want['why']}"), stderr
    assert "1 runs (0 failed)" in stdout
    assert sorted(p.name for p in (folder / store.RUNS_DIR).iterdir()) == listing  # report only reads
    assert list(pd.read_parquet(folder / store.RESULTS_FILE)["run_id"]) == RUN_IDS[:1]


def test_resume_sets_a_damaged_run_aside_and_runs_it_again(folder, finished):
    want = _break_runs(folder)
    code, stdout, stderr = _cli("resume", str(folder), "--workers", "0", "--quiet")
    assert code == 0, stderr
    assert f"warning: {want['run']}: {want['why']}" in stderr and "set aside as" in stderr
    assert "2 runs, 1 run now" in stdout
    runs = sorted(p.name for p in (folder / store.RUNS_DIR).iterdir())
    assert runs == [f"{RUN_IDS[0]}.parquet", f"{RUN_IDS[1]}.parquet", f"{RUN_IDS[1]}.parquet.damaged"]
    again = pd.read_parquet(folder / store.RESULTS_FILE)
    ref = pd.read_parquet(finished / store.RESULTS_FILE)
    assert list(again["run_id"]) == RUN_IDS
    for col in ("seed", "tp_pct", "fp_pct", "n_frames"):  # the same run again: the same numbers
        assert list(again[col]) == list(ref[col]), col


@pytest.mark.parametrize("damage, why", [
    (lambda t: t.set_column(t.column_names.index("tp_pct"), "tp_pct", pa.array(["x"])), "column 'tp_pct' is string"),
    (lambda t: t.set_column(t.column_names.index("run_id"), "run_id", pa.array([RUN_IDS[0]])), "holds run"),
    (lambda t: t.set_column(t.column_names.index("status"), "status", pa.array(["maybe"])), "status 'maybe'"),
    (lambda t: pa.concat_tables([t, t]), "2 rows, a run file has one"),
    (lambda t: t.drop_columns(["run_index"]), "no int64 column 'run_index'"),
])
def test_run_file_with_wrong_content_is_damaged(folder, damage, why):
    run = store.run_path(folder, RUN_IDS[1])
    pq.write_table(damage(pq.read_table(run)), run)
    warnings: list[str] = []
    assert list(store.finished_runs(folder, warn=warnings.append)) == RUN_IDS[:1]
    assert len(warnings) == 1 and warnings[0].startswith(f"{run}: {why}"), warnings
    assert run.is_file()  # without clean: only read
    store.finished_runs(folder, clean=True, warn=warnings.append)
    assert not run.exists() and run.with_name(run.name + store.DAMAGED_SUFFIX).is_file()


def test_results_parquet_is_rebuilt_or_refused(folder):
    results = folder / store.RESULTS_FILE
    results.write_bytes(b"garbage")
    code, _, stderr = _cli("resume", str(folder), "--workers", "0", "--quiet")  # nothing to run: rebuilt
    assert code == 0, stderr
    assert list(pd.read_parquet(results)["run_id"]) == RUN_IDS
    results.unlink()
    results.mkdir()
    code, _, stderr = _cli("report", str(folder))
    assert code == 2 and _one_error_line(stderr).startswith(f"{results}: not a file")


def test_runs_folder_that_is_a_file(folder):
    shutil.rmtree(folder / store.RUNS_DIR)
    (folder / store.RUNS_DIR).write_text("x")
    for command in (["report", str(folder)], ["resume", str(folder), "--workers", "0"]):
        code, _, stderr = _cli(*command)
        assert code == 2 and _one_error_line(stderr).startswith(f"{folder / store.RUNS_DIR}: not a folder"), stderr


# ---------------------------------------------------------------------------------- the lock


def _hold_lock(folder: Path) -> subprocess.Popen:
    code = ("import sys, time\nfrom roadtrack.testbed.campaign import store\nwith store.locked(sys.argv[1]):\n"
            "    print('locked', flush=True)\n    time.sleep(60)\n")
    proc = subprocess.Popen([sys.executable, "-c", code, str(folder)], cwd=REPO, stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline() == "locked\n"
    return proc


def test_second_campaign_process_on_a_folder_is_refused_and_sigkill_leaves_no_stale_lock(folder):
    holder = _hold_lock(folder)
    try:
        code, _, stderr = _cli("resume", str(folder), "--workers", "0", "--quiet")
        assert code == 2
        assert _one_error_line(stderr) == (f"{folder} is in use by another campaign process (pid {holder.pid}); "
                                           "wait for it or stop it")
        # report only reads: it runs beside the campaign and leaves its temp files alone
        tmp = folder / store.RUNS_DIR / ".x.parquet.tmp-999999"
        tmp.write_bytes(b"being written")
        code, stdout, stderr = _cli("report", str(folder))
        assert code == 0 and "2 runs (0 failed)" in stdout, stderr
        assert tmp.is_file()
    finally:
        holder.send_signal(signal.SIGKILL)
        holder.wait(timeout=30)
    code, stdout, stderr = _cli("resume", str(folder), "--workers", "0", "--quiet")  # the kernel freed the lock
    assert code == 0 and "0 run now" in stdout, stderr
    assert not tmp.exists()  # the lock holder cleans up


def test_lock_is_per_process_call(folder):
    with store.locked(folder):
        with pytest.raises(ConfigError, match=f"pid {os.getpid()}"):
            with store.locked(folder):
                pass
    with store.locked(folder):  # released on exit
        pass


# ---------------------------------------------------------------------------------- --scheduler and --out


@pytest.mark.parametrize("address, message", [
    ("not-an-address", "missing port number"),
    ("http://host:8786", "unknown address scheme 'http'"),
    ("tcp://host:0", "port 0 is not in 1..65535"),
    ("tcp://host:x", "invalid literal"),
    ("tcp://:8786", "no host"),
    ("inproc://x", "exist only inside one process"),
])
def test_malformed_scheduler_is_exit_2_before_anything_is_written(tmp_path, address, message):
    path = tmp_path / "c.toml"
    path.write_text(CAMPAIGN)
    out = tmp_path / "out"
    code, _, stderr = _cli("run", str(path), "--out", str(out), "--scheduler", address)
    line = _one_error_line(stderr)
    assert code == 2 and line.startswith(f"--scheduler: {address!r} is not a Dask scheduler address"), line
    assert message in line
    assert "tcp://host:port" in line  # what is allowed
    assert not out.exists()


def _closed_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_unreachable_scheduler_is_exit_1_and_no_folder(tmp_path, folder):
    path = tmp_path / "c.toml"
    path.write_text(CAMPAIGN)
    out = tmp_path / "out"
    address = f"tcp://127.0.0.1:{_closed_port()}"
    code, _, stderr = _cli("run", str(path), "--out", str(out), "--scheduler", address)
    assert code == 1 and _one_error_line(stderr).startswith(f"--scheduler {address}: cannot connect (connection "
                                                             "refused); start a Dask scheduler there")
    assert not out.exists()
    before = {p.name: p.stat().st_mtime_ns for p in (folder / store.RUNS_DIR).iterdir()}
    code, _, stderr = _cli("resume", str(folder), "--scheduler", address)
    assert code == 1 and "cannot connect (connection refused)" in _one_error_line(stderr)
    assert {p.name: p.stat().st_mtime_ns for p in (folder / store.RUNS_DIR).iterdir()} == before


def test_a_listener_that_is_not_a_dask_scheduler_times_out_in_seconds(tmp_path):
    path = tmp_path / "c.toml"
    path.write_text(CAMPAIGN)
    out = tmp_path / "out"
    with socket.socket() as silent:  # accepts connections (the kernel's backlog) and never answers
        silent.bind(("127.0.0.1", 0))
        silent.listen(4)
        address = f"tcp://127.0.0.1:{silent.getsockname()[1]}"
        t0 = time.monotonic()
        code, _, stderr = _cli("run", str(path), "--out", str(out), "--scheduler", address)
        assert 2.5 < time.monotonic() - t0 < 20.0  # the 3 s handshake timeout (on a loaded machine)
    assert code == 1 and _one_error_line(stderr).startswith(f"--scheduler {address}: no Dask scheduler answered "
                                                             "within 3 s")
    assert not out.exists()


def test_out_that_is_a_file_or_not_creatable(tmp_path):
    path = tmp_path / "c.toml"
    path.write_text(CAMPAIGN)
    code, _, stderr = _cli("run", str(path), "--out", str(path))
    assert code == 2 and _one_error_line(stderr) == f"{path} is a file, not a folder: choose another --out"
    code, _, stderr = _cli("run", str(path), "--out", str(path / "sub"))
    assert code == 2 and "cannot create the results folder (not a directory)" in _one_error_line(stderr)


def test_create_removes_a_half_made_folder(tmp_path):
    path = tmp_path / "c.toml"
    path.write_text(CAMPAIGN)
    campaign = load_campaign(path)
    out = tmp_path / "out"
    with pytest.raises(FileNotFoundError):
        store.create(out, tmp_path / "gone.toml", campaign)  # the campaign file is copied last
    assert not out.exists()


def test_debug_shows_the_traceback(tmp_path):
    code, _, stderr = _cli("--debug", "report", str(tmp_path / "nowhere"))
    assert code == 2 and "Traceback" in stderr and stderr.rstrip().endswith("no such campaign folder")
    code, _, stderr = _cli("report", str(tmp_path / "nowhere"), "--debug")
    assert code == 2 and "Traceback" in stderr
