"""Sense once, track many from Python: the memory a run's sensed frames hold, whole and light, and the time of a
pass from the sensing cache against sensing anew, measured in one run on this machine.

    .venv/bin/python benchmarks/bench_sense_stream.py [--scenario dense_motorway] [--duration 60]

Three fresh subprocesses (their memory does not mix), on the first ``--duration`` seconds of ``--scenario``:

1. ``list(testbed.sense(scn))``: frames as sensed (point cloud, perception, float64 range images); timed.
2. ``list(testbed.sense(scn, light=True))`` (testbed.sensing.light).
3. ``testbed.sense(scn, sensing_cache=DIR, light=True)`` read through twice: the first pass senses and stores the
   entry, the second reads it back; each timed, and the peak memory of the second pass (it streams: one frame at a
   time) measured.

Per variant: the bytes the held frames take (tracemalloc: numpy reports its buffers to it), the RSS growth, and
bytes per frame. Prints the ratios whole / light (memory) and sensing anew / second pass from the cache (time).
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

os.environ.setdefault("RERUN_ANALYTICS", "0")
REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))
PAGE = os.sysconf("SC_PAGE_SIZE")


def rss() -> int:
    """Resident set size of this process now [bytes]."""
    with open("/proc/self/statm") as fh:
        return int(fh.read().split()[1]) * PAGE


def child(variant: str, scenario: str, duration: float) -> dict:
    """One measured variant in this process (see the module docstring)."""
    from roadtrack.testbed.common.threads import one_thread_per_process

    one_thread_per_process()
    from roadtrack import testbed

    scn = testbed.load_scenario(scenario, {"duration_s": duration})
    next(iter(testbed.sense(testbed.load_scenario(scenario, {"duration_s": 0.1}))))  # imports and kernels warm
    out: dict = {"variant": variant, "frames": scn.n_frames}
    r0 = rss()
    tracemalloc.start()
    t0 = time.perf_counter()
    if variant in ("whole", "light"):
        held = list(testbed.sense(scn, light=variant == "light"))
        out["seconds"] = time.perf_counter() - t0
        out["held_bytes"] = tracemalloc.get_traced_memory()[0]
        out["rss_growth"] = rss() - r0
        out["n"] = len(held)
        return out
    with tempfile.TemporaryDirectory() as cache:
        n1 = sum(1 for _ in testbed.sense(scn, sensing_cache=cache, light=True))
        out["first_pass_s"] = time.perf_counter() - t0
        tracemalloc.reset_peak()
        base = tracemalloc.get_traced_memory()[0]
        t1 = time.perf_counter()
        n2 = sum(1 for _ in testbed.sense(scn, sensing_cache=cache, light=True))
        out["second_pass_s"] = time.perf_counter() - t1
        out["second_pass_peak_bytes"] = tracemalloc.get_traced_memory()[1] - base
        out["n"] = min(n1, n2)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", default="dense_motorway")
    ap.add_argument("--duration", type=float, default=60.0, help="simulated seconds")
    ap.add_argument("--child", choices=("whole", "light", "cache"), help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        print(json.dumps(child(args.child, args.scenario, args.duration)))
        return
    res = {}
    for variant in ("whole", "light", "cache"):
        proc = subprocess.run([sys.executable, __file__, "--child", variant, "--scenario", args.scenario,
                               "--duration", str(args.duration)], capture_output=True, text=True, check=True)
        res[variant] = json.loads(proc.stdout.strip().splitlines()[-1])
        print(variant, res[variant], flush=True)
    w, li, c = res["whole"], res["light"], res["cache"]
    mb = 2 ** 20
    print(f"{args.scenario}, {args.duration:g} s ({w['n']} frames):")
    print(f"  held whole: {w['held_bytes'] / mb:.1f} MB ({w['held_bytes'] / w['n'] / mb:.2f} MB a frame; "
          f"RSS +{w['rss_growth'] / mb:.0f} MB); light: {li['held_bytes'] / mb:.1f} MB "
          f"({li['held_bytes'] / li['n'] / 1024:.0f} kB a frame; RSS +{li['rss_growth'] / mb:.0f} MB); "
          f"ratio {w['held_bytes'] / li['held_bytes']:.0f}x")
    print(f"  sensing anew {w['seconds']:.1f} s; into the cache {c['first_pass_s']:.1f} s; from the cache "
          f"{c['second_pass_s']:.2f} s (peak {c['second_pass_peak_bytes'] / mb:.1f} MB, streamed); "
          f"ratio anew / from the cache {w['seconds'] / c['second_pass_s']:.0f}x")


if __name__ == "__main__":
    main()
