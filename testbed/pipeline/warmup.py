"""Compile the sensors' numba kernels into their on-disk cache at set-up, so that no user's run compiles.

``bin/setup`` runs ``python -m testbed.pipeline.warmup``: a few frames of the highway benchmark with the full
perception stack (trucks, box fits, the occlusion-aware P_D) and with the thesis pipeline, which between them
call every kernel of :data:`KERNEL_MODULES`. numba keeps what it compiled next to the sources
(``sensors/__pycache__``), keyed by each source file, so the first ``bin/demo`` after ``bin/setup`` reports
steady-state timings (before, its first run compiled inside the run: 240 ms per frame against 81 ms). With a
warm cache this takes a few seconds and compiles nothing.
"""
from __future__ import annotations

import importlib
import os
import sys
import time

KERNEL_MODULES = ("sensors.raycast", "sensors.perception_jit", "sensors.boxfit_jit")
"""The modules of numba kernels (``@njit(cache=True)``); their public functions are the kernels a run calls."""
RUNS = (("highway_benchmark", {"duration_s": 0.5}),
        ("highway_benchmark", {"duration_s": 0.5, "sensor.pipeline": "thesis"}))


def kernels() -> dict[str, object]:
    """``module.name`` -> numba dispatcher of every public kernel of :data:`KERNEL_MODULES`."""
    from numba.core.registry import CPUDispatcher

    out = {}
    for m in KERNEL_MODULES:
        mod = importlib.import_module(m)
        out.update({f"{m}.{k}": v for k, v in vars(mod).items()
                    if isinstance(v, CPUDispatcher) and not k.startswith("_")})
    return out


def warm() -> tuple[int, int, list[str]]:
    """Run :data:`RUNS` (no output written); returns (kernels, kernels compiled now, kernels never called)."""
    from ..scenario.spec import load_scenario
    from .run import run_scenario

    for name, overrides in RUNS:
        run_scenario(load_scenario(name, overrides), record=False)
    ks = kernels()
    compiled = sum(1 for d in ks.values() if any(d.stats.cache_misses.values()))
    unused = sorted(k for k, d in ks.items() if not d.signatures)
    return len(ks), compiled, unused


def main() -> int:
    os.environ.setdefault("RERUN_ANALYTICS", "0")
    t0 = time.perf_counter()
    n, compiled, unused = warm()
    print(f"warm-up: {n} numba kernels cached ({compiled} compiled now) in {time.perf_counter() - t0:.1f} s")
    if unused:
        print(f"warm-up: never called, so compiled in a user's run: {', '.join(unused)}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
