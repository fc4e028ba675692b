"""Thread pools sized for the work (testbed/common/threads.py): the command line runs with one BLAS and OpenMP
thread per process unless the user set the variables; campaign workers size the ones the tool set."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from roadtrack.testbed.common.threads import DEFAULTED, THREAD_VARS, one_thread_per_process, set_by_user

REPO = Path(__file__).resolve().parents[1]
SHOW = ("import os, sys\nfrom roadtrack.testbed.cli.main import main\nbefore = 'numpy' in sys.modules\nmain(['keys'])\n"
        "print(before, *(os.environ.get(v) for v in %r), file=sys.stderr)" % (THREAD_VARS,))


def test_missing_variables_become_one_and_the_users_own_are_kept():
    env = {"MKL_NUM_THREADS": "4"}
    assert one_thread_per_process(env) == ["OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS"]
    assert env["OMP_NUM_THREADS"] == env["OPENBLAS_NUM_THREADS"] == "1" and env["MKL_NUM_THREADS"] == "4"
    assert set_by_user("MKL_NUM_THREADS", env) and not set_by_user("OMP_NUM_THREADS", env)
    assert one_thread_per_process(env) == [] and env[DEFAULTED] == "OMP_NUM_THREADS,OPENBLAS_NUM_THREADS"


def test_the_command_line_sets_them_before_numpy_is_imported():
    base = {k: v for k, v in os.environ.items() if k not in THREAD_VARS and k != DEFAULTED}
    out = subprocess.run([sys.executable, "-c", SHOW], capture_output=True, text=True, cwd=REPO, timeout=120,
                         env=base)
    assert out.stderr.strip().splitlines()[-1] == "False 1 1 1"  # numpy not yet imported when main() starts; each variable 1
    mine = subprocess.run([sys.executable, "-c", SHOW], capture_output=True, text=True, cwd=REPO, timeout=120,
                          env={**base, "OMP_NUM_THREADS": "2"})
    assert mine.stderr.strip().splitlines()[-1] == "False 2 1 1"
