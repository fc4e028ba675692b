"""No numba kernel is compiled in a user's run once set-up has warmed the cache (testbed/pipeline/warmup.py):
after the warm-up, a fresh process runs the full stack and the thesis pipeline with numba's compile events
recorded, and records none."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
RUN = """
import numba.core.event as ev
from roadtrack.testbed.pipeline.run import run_scenario
from roadtrack.testbed.scenario.spec import load_scenario
with ev.install_recorder("numba:compile") as rec:
    for name, over in [("highway_benchmark", {"duration_s": 1.0}), ("dense_motorway", {"duration_s": 1.0}),
                       ("cut_in_out", {"duration_s": 1.0, "sensor.pipeline": "thesis"})]:
        run_scenario(load_scenario(name, over), record=False)
print(len([e for e in rec.buffer if e[1].is_start]))
print(sorted({str(e[1].data["dispatcher"].py_func.__qualname__) for e in rec.buffer if e[1].is_start}))
"""


def _python(code: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO, timeout=900,
                          env={**os.environ, "RERUN_ANALYTICS": "0"})


def test_the_warm_up_reaches_every_kernel_and_a_run_after_it_compiles_none():
    warm = subprocess.run([sys.executable, "-m", "roadtrack.testbed.pipeline.warmup"], capture_output=True, text=True,
                          cwd=REPO, timeout=900)
    assert warm.returncode == 0, warm.stderr
    assert warm.stdout.startswith("warm-up: ") and "numba kernels cached" in warm.stdout
    out = _python(RUN)
    assert out.returncode == 0, out.stderr[-2000:]
    count, names = out.stdout.strip().splitlines()[-2:]
    assert count == "0", f"compiled in a run after the warm-up: {names}"


def test_the_recorder_sees_a_compile_when_there_is_one(tmp_path):
    """The oracle can fail: a fresh kernel compiled inside the recorder is counted."""
    code = ("import numba, numba.core.event as ev\n"
            "f = numba.njit(lambda x: x + 1)\n"
            "with ev.install_recorder('numba:compile') as rec:\n"
            "    f(1.0)\n"
            "print(len([e for e in rec.buffer if e[1].is_start]))\n")
    out = _python(code)
    assert out.returncode == 0 and out.stdout.strip() == "1", out.stderr


def test_every_module_with_cached_kernels_is_warmed():
    from roadtrack.testbed.pipeline.warmup import KERNEL_MODULES

    with_kernels = {f"roadtrack.sensors.{p.stem}" for p in (REPO / "sensors").glob("*.py")
                    if "@njit(cache=True)" in p.read_text(encoding="utf-8")}
    assert with_kernels == set(KERNEL_MODULES)


def test_the_first_compile_note_is_one_line_once_and_only_for_the_watched_modules():
    """testbed's command line wraps every command but `warmup` in first_compile_note: a run that compiles says so
    once, on stderr; a compilation of someone else's function says nothing."""
    import io

    import numba

    from roadtrack.testbed.pipeline.warmup import COMPILE_NOTE, first_compile_note

    def add(x):
        return x + 1

    ours, theirs = numba.njit(add), numba.njit(lambda x: x * 2)
    theirs.py_func.__module__ = "someone.else"
    stream = io.StringIO()
    with first_compile_note(stream, modules=(__name__,)):
        theirs(1.0)
        assert stream.getvalue() == ""
        ours(1.0)
        ours(1)  # a second signature: compiled again, not noted again
    assert len(ours.signatures) == 2
    assert stream.getvalue() == COMPILE_NOTE + "\n" and COMPILE_NOTE.startswith("note: ")
    ours(2.0j)  # outside the block: nothing
    assert stream.getvalue() == COMPILE_NOTE + "\n"


def test_testbed_warmup_is_a_command_and_says_where_the_cache_is():
    out = subprocess.run([sys.executable, "-m", "roadtrack.testbed.cli.main", "warmup", "--help"], capture_output=True,
                         text=True, cwd=REPO, timeout=300)
    assert out.returncode == 0 and "numba kernels" in out.stdout
    from roadtrack.testbed.pipeline.warmup import cache_folders

    folders = cache_folders()
    assert folders and all(os.path.isdir(f) and os.access(f, os.W_OK) for f in folders), folders
