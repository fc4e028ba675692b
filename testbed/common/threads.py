"""Thread pools sized for the work: one BLAS and OpenMP thread per process unless the user chose.

A frame's arrays are small (a 60,000-float dot product, 3x3 solves): a second BLAS thread gains nothing on them,
and on a busy machine it waits for a core. Measured here: ``np.dot`` of two 60,000-float vectors took 127 us on
one OpenBLAS thread and 6.6 ms on two while the other core was busy, and a highway run's ground segmentation went
from ~3 to 99 ms per frame. The command line therefore sets, before numpy or open3d is imported, each of
:data:`THREAD_VARS` that is not already set to 1 (set one yourself to override it, e.g. ``OMP_NUM_THREADS=2
testbed run ...``). The Python API leaves them to the caller; campaign workers size them per worker
(testbed/campaign/engine.py).
"""
from __future__ import annotations

import os
from typing import MutableMapping

THREAD_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")
DEFAULTED = "ROADTRACK_DEFAULTED_THREAD_VARS"
"""The variable naming those of THREAD_VARS that the tool set itself (so a campaign worker may size them)."""


def one_thread_per_process(environ: MutableMapping[str, str] = os.environ) -> list[str]:
    """Set each of :data:`THREAD_VARS` missing from ``environ`` to "1"; returns the names it set (also listed in
    ``environ[DEFAULTED]``). Effective only before numpy and open3d are imported (their pools read them once)."""
    added = [v for v in THREAD_VARS if not environ.get(v)]
    for v in added:
        environ[v] = "1"
    done = [v for v in environ.get(DEFAULTED, "").split(",") if v]
    environ[DEFAULTED] = ",".join(dict.fromkeys(done + added))
    return added


def set_by_user(var: str, environ: MutableMapping[str, str] = os.environ) -> bool:
    """Whether the user set ``var`` (it is set, and not by :func:`one_thread_per_process`)."""
    return bool(environ.get(var)) and var not in environ.get(DEFAULTED, "").split(",")
