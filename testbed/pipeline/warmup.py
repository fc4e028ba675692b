"""Compile the sensors' numba kernels into their on-disk cache ahead of a run, so that no user's run compiles.

``testbed warmup`` (or ``python -m roadtrack.testbed.pipeline.warmup``; ``bin/setup`` runs it in a checkout): a few frames
of the highway benchmark with the full perception stack (trucks, box fits, the occlusion-aware P_D) and with the
thesis pipeline, which between them call every kernel of :data:`KERNEL_MODULES`. numba keeps what it compiled
next to the sources (``sensors/__pycache__``, in a checkout or in site-packages), or, where that folder is not
writable (a package installed by another user), in the user's cache folder (``~/.cache/numba``; ``NUMBA_CACHE_DIR``
chooses another), keyed by each source file, so the first run after it reports steady-state timings (before, the
first run after an install compiled inside the run: 1547 ms per frame, then 102). With a warm cache this takes a
few seconds and compiles nothing.

A run that has to compile anyway (no warm-up after an install or an update) says so in one line on stderr,
:data:`COMPILE_NOTE`, the first time it compiles (:func:`first_compile_note`, installed by the command line).
"""
from __future__ import annotations

import contextlib
import importlib
import os
import sys
import time
from collections.abc import Callable, Iterator
from typing import TextIO

KERNEL_MODULES = ("roadtrack.sensors.raycast", "roadtrack.sensors.perception_jit", "roadtrack.sensors.boxfit_jit",
                  "roadtrack.sensors.occlusion_jit", "roadtrack.sensors.roi_jit")
"""The modules of numba kernels (``@njit(cache=True)``); their public functions are the kernels a run calls."""
RUNS = (("highway_benchmark", {"duration_s": 0.5}),
        ("highway_benchmark", {"duration_s": 0.5, "sensor.pipeline": "thesis"}))
COMPILE_NOTE = ("note: compiling the sensors' numba kernels into their cache (once after an install or an update, "
                "about a minute; `testbed warmup` does it ahead of a run)")


def kernels() -> dict[str, object]:
    """``module.name`` -> numba dispatcher of every public kernel of :data:`KERNEL_MODULES`."""
    from numba.core.registry import CPUDispatcher

    out = {}
    for m in KERNEL_MODULES:
        mod = importlib.import_module(m)
        out.update({f"{m}.{k}": v for k, v in vars(mod).items()
                    if isinstance(v, CPUDispatcher) and not k.startswith("_")})
    return out


def cache_folders() -> list[str]:
    """The folders numba keeps the kernels' compiled code in (chosen by numba per source file: ``__pycache__``
    beside it if writable, else the user's cache folder, or ``NUMBA_CACHE_DIR``); [] if numba does not say."""
    folders = set()
    for d in kernels().values():
        path = getattr(getattr(d, "_cache", None), "cache_path", None)  # numba's Cache.cache_path
        if isinstance(path, str):
            folders.add(path)
    return sorted(folders)


@contextlib.contextmanager
def watch_compiles(on_compile: Callable[[str], None], modules: tuple[str, ...] = KERNEL_MODULES) -> Iterator[None]:
    """Within the block, ``on_compile("module.function")`` at the start of every numba compilation of a function
    defined in one of ``modules`` (numba's ``numba:compile`` event)."""
    from numba.core import event

    class Watch(event.Listener):
        def on_start(self, ev) -> None:
            func = getattr(ev.data.get("dispatcher"), "py_func", None)
            module = getattr(func, "__module__", None)
            if module in modules:
                on_compile(f"{module}.{func.__name__}")

        def on_end(self, ev) -> None:
            pass

    listener = Watch()
    event.register("numba:compile", listener)
    try:
        yield
    finally:
        event.unregister("numba:compile", listener)


@contextlib.contextmanager
def first_compile_note(stream: TextIO | None = None, modules: tuple[str, ...] = KERNEL_MODULES) -> Iterator[None]:
    """Within the block, :data:`COMPILE_NOTE` once on ``stream`` (default stderr, above any progress bar) when a
    kernel of ``modules`` is first compiled; nothing when every kernel comes from the cache."""
    noted = False

    def note(_name: str) -> None:
        nonlocal noted
        if not noted:
            noted = True
            from tqdm import tqdm

            tqdm.write(COMPILE_NOTE, file=stream if stream is not None else sys.stderr)

    with watch_compiles(note, modules):
        yield


def warm(on_compile: Callable[[str], None] | None = None) -> tuple[int, int, list[str]]:
    """Run :data:`RUNS` (no output written); returns (kernels, kernels compiled now, kernels never called).
    ``on_compile("module.function")`` is called at each compilation (see :func:`watch_compiles`)."""
    from ..scenario.spec import load_scenario
    from .run import run_scenario

    with watch_compiles(on_compile or (lambda _name: None)):
        for name, overrides in RUNS:
            run_scenario(load_scenario(name, overrides), record=False)
    ks = kernels()
    compiled = sum(1 for d in ks.values() if any(d.stats.cache_misses.values()))
    unused = sorted(k for k, d in ks.items() if not d.signatures)
    return len(ks), compiled, unused


def main(stream: TextIO | None = None) -> int:
    """``testbed warmup``: a progress line while it compiles (rewritten in place on a terminal), then
    ``warm-up: N numba kernels cached (M compiled now) in S s`` and where; 1 if a kernel was never called."""
    out = stream if stream is not None else sys.stdout
    os.environ.setdefault("RERUN_ANALYTICS", "0")
    live = out.isatty()
    count = 0

    def progress(name: str) -> None:
        nonlocal count
        count += 1
        if live:
            out.write(f"\rwarm-up: compiling kernel {count}: {name:<50.50}")
            out.flush()

    print("warm-up: running a few frames of every pipeline to fill numba's cache (about a minute the first time, "
          "a few seconds when it is warm)", file=out, flush=True)
    t0 = time.perf_counter()
    n, compiled, unused = warm(progress)
    if live and count:
        out.write("\r" + " " * 79 + "\r")
    where = ", ".join(cache_folders()) or "numba's cache"
    print(f"warm-up: {n} numba kernels cached ({compiled} compiled now) in {time.perf_counter() - t0:.1f} s, in "
          f"{where}", file=out, flush=True)
    if unused:
        print(f"error: warm-up: never called, so compiled in a user's run: {', '.join(unused)}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
