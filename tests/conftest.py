"""Shared fixtures: one short recorded run of the real pipeline, reused by the tests of its outputs (made once per
test session, also when pytest-xdist spreads the tests over several worker processes: see :func:`made_once`)."""
from __future__ import annotations

import fcntl
import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Callable

import pytest

from roadtrack.testbed.common.threads import one_thread_per_process

# One BLAS / OpenMP thread per process, as `testbed` gives its own runs (testbed/common/threads.py), also for the
# runs the tests make through the Python API in the pytest(-xdist) processes: with the default of a thread per core,
# the two xdist workers' pools wait for each other's cores (test_end_to_end + test_record_levels: 78-82 s -> 43-45 s
# wall, 115 -> 73 CPU s, on this 2-core machine). Set before numpy is first imported (its pools read them once); a
# variable the user set is kept, the ones set here are listed as the tool's own (campaign workers size them).
one_thread_per_process()

REPO = Path(__file__).resolve().parent.parent


def cli(*args: str, timeout: float = 300) -> subprocess.CompletedProcess:
    """``testbed ARGS`` in a subprocess (this interpreter, the repository as working folder)."""
    return subprocess.run([sys.executable, "-m", "roadtrack.testbed.cli", *args], capture_output=True, text=True, cwd=REPO,
                          timeout=timeout, env=dict(os.environ, RERUN_ANALYTICS="0"))


def session_folder(tmp_path_factory) -> Path:
    """The temporary folder of the whole test session: with pytest-xdist, the one above every worker's own
    (``.../pytest-N/popen-gw0`` -> ``.../pytest-N``); without it, the session's base folder."""
    base = tmp_path_factory.getbasetemp()
    return base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base


def made_once(tmp_path_factory, name: str, make: Callable[[Path], dict]) -> tuple[Path, dict]:
    """``make(folder)`` run once per test session in ``<session folder>/shared-<name>``, whichever worker asks
    first; the others wait on a file lock and reuse the folder. ``make`` returns JSON-able facts about what it
    made (kept beside it in ``made.json``). If ``make`` raises, nothing is kept and the next caller tries again.
    (The folder, the facts.)"""
    folder = session_folder(tmp_path_factory) / f"shared-{name}"
    folder.mkdir(exist_ok=True)
    with open(folder / ".lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes
        done = folder / "made.json"
        if not done.is_file():
            done.write_text(json.dumps(make(folder)))
        return folder, json.loads(done.read_text())


def _record_short_run(folder: Path) -> dict:
    proc = cli("run", "cut_in_out", "--tracker", "nn-kf", "--set", "duration_s=8", "--out", str(folder / "run"),
               "--quiet")
    assert proc.returncode == 0, proc.stderr
    return {"args": proc.args, "returncode": proc.returncode, "stdout": proc.stdout, "stderr": proc.stderr}


@pytest.fixture(scope="session")
def short_run(tmp_path_factory) -> tuple[Path, subprocess.CompletedProcess]:
    """cut_in_out with nn-kf for 8 s (about 10 s to run): the cutting-in car's track T2 loses the car to T3 at
    7.1 s and takes it back at 7.2 s (two relabels, cause merge); recorded, with timeline.png. (The run folder,
    the finished ``testbed run`` process.)"""
    folder, facts = made_once(tmp_path_factory, "short_run", _record_short_run)
    return folder / "run", subprocess.CompletedProcess(**facts)


@pytest.fixture(scope="session")
def short_run_csv(short_run, tmp_path_factory) -> tuple[Path, subprocess.CompletedProcess]:
    """:func:`short_run` exported by ``testbed export RUN --format csv`` (made once per test session, read only by
    the tests of the export and of the trackers that read it). (The CSV folder, the finished ``testbed export``
    process.)"""
    run, _ = short_run

    def export(folder: Path) -> dict:
        proc = cli("export", str(run), "--format", "csv", "--out", str(folder / "csv"), timeout=120)
        assert proc.returncode == 0, proc.stderr
        return {"args": proc.args, "returncode": proc.returncode, "stdout": proc.stdout, "stderr": proc.stderr}

    folder, facts = made_once(tmp_path_factory, "short_run_csv", export)
    return folder / "csv", subprocess.CompletedProcess(**facts)


def _sense_cut_in_out(folder: Path) -> dict:
    from roadtrack import testbed

    frames = sum(1 for _ in testbed.sense(testbed.load_scenario("cut_in_out"), sensing_cache=folder / "cache"))
    return {"frames": frames}


@pytest.fixture(scope="session")
def cut_in_out_sensing(tmp_path_factory) -> Path:
    """A sensing cache (testbed.sensing.cache) holding the shipped cut_in_out's sensed frames (all 16 s), sensed once
    per test session for the tests that run trackers on that traffic (a run from the cache is identical to one
    from scratch: tests/test_sensing_cache.py). (The cache folder, for ``sensing_cache=``.)"""
    folder, facts = made_once(tmp_path_factory, "cut_in_out_sensing", _sense_cut_in_out)
    assert facts["frames"] == 161
    return folder / "cache"
