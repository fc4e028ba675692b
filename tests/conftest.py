"""Shared fixtures: one short recorded run of the real pipeline, reused by the tests of its outputs."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent


def cli(*args: str, timeout: float = 300) -> subprocess.CompletedProcess:
    """``testbed ARGS`` in a subprocess (this interpreter, the repository as working folder)."""
    return subprocess.run([sys.executable, "-m", "testbed.cli", *args], capture_output=True, text=True, cwd=REPO,
                          timeout=timeout, env=dict(os.environ, RERUN_ANALYTICS="0"))


@pytest.fixture(scope="session")
def short_run(tmp_path_factory) -> tuple[Path, subprocess.CompletedProcess]:
    """cut_in_out with nn-kf for 8 s (about 10 s to run): the cutting-in car's track T2 loses the car to T3 at
    7.1 s and takes it back at 7.2 s (two relabels, cause merge); recorded, with timeline.png. (The run folder,
    the finished ``testbed run`` process.)"""
    out = tmp_path_factory.mktemp("short_run") / "run"
    proc = cli("run", "cut_in_out", "--tracker", "nn-kf", "--set", "duration_s=8", "--out", str(out), "--quiet")
    assert proc.returncode == 0, proc.stderr
    return out, proc
