"""Peak memory of a long run against a short one: a run's memory must not grow with its length.

    .venv/bin/python benchmarks/bench_memory.py [--scenario convoy] [--short 60] [--long 1200]
                                          [--recording both|on|off] [--sample-every 100]

Runs ``run_scenario`` for ``--short`` and ``--long`` simulated seconds of the same scenario (same road,
long enough for the long run: ``road.length_m`` is set from the fastest car's speed), with recording to a
temporary directory and without. Each run is a fresh subprocess, so their peaks do not mix. Prints per run
the peak RSS (``getrusage`` ``ru_maxrss``), the RSS after the first ``--sample-every`` frames and the end
of the loop (sampled from ``/proc/self/statm``), the growth per frame (least-squares slope of the samples
after the first quarter of the run) and the ratio long / short of the peaks. Target: ratio <= 1.2.
The peak includes the end of the run (scoring, parquet tables, closing the recording); a recording of
more than ``testbed.recording.recorder.FOOTER_MAX_FRAMES`` frames is written without rerun's footer.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time

os.environ.setdefault("RERUN_ANALYTICS", "0")

TARGET_RATIO = 1.2
PAGE_MB = os.sysconf("SC_PAGE_SIZE") / 2**20


def rss_mb() -> float:
    """Resident set size of this process now [MB]."""
    with open("/proc/self/statm") as fh:
        return int(fh.read().split()[1]) * PAGE_MB


def peak_mb() -> float:
    """Peak resident set size of this process so far [MB] (Linux reports ru_maxrss in kB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def scenario(name: str, duration_s: float, longest_s: float):
    """``name`` lasting ``duration_s``, on a straight road long enough for ``longest_s`` of driving."""
    from roadtrack.testbed.scenario.spec import load_scenario

    base = load_scenario(name)
    speed = max(max(v.speed_mps, v.target_speed_mps or 0.0) for v in base.all_vehicles())
    start = max(v.position_m for v in base.all_vehicles())
    length = round(start + 1.1 * speed * longest_s + 500.0, -2)
    return load_scenario(name, {"duration_s": duration_s, "road.kind": "straight", "road.length_m": length})


def child(args: argparse.Namespace) -> None:
    """One measured run in this process; prints a JSON line of its memory figures."""
    from roadtrack.testbed.pipeline.run import run_scenario

    scn = scenario(args.scenario, args.duration, args.longest)
    samples: list[tuple[int, float]] = [(0, rss_mb())]

    def on_frame(k: int, _n: int) -> None:
        if k % args.sample_every == 0:
            samples.append((k, rss_mb()))

    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        res = run_scenario(scn, out_dir=tmp, record=args.record, on_frame=on_frame)
        rrd_mb = os.path.getsize(os.path.join(tmp, "run.rrd")) / 2**20 if args.record else 0.0
    print(json.dumps(dict(frames=res.n_frames, seconds=time.perf_counter() - t0, peak_mb=peak_mb(),
                          samples=samples, rrd_mb=rrd_mb)))


def measure(args: argparse.Namespace, duration: float, record: bool) -> dict:
    """Run ``child`` in a fresh interpreter and return its figures."""
    cmd = [sys.executable, os.path.abspath(__file__), "--child", "--scenario", args.scenario,
           "--duration", str(duration), "--longest", str(args.long), "--sample-every", str(args.sample_every)]
    if record:
        cmd.append("--record")
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        raise SystemExit(f"run of {duration:g} s failed:\n{proc.stderr}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def growth_kb_per_frame(samples: list[tuple[int, float]]) -> float:
    """Least-squares slope of RSS over frames, after the first quarter of the run (warm-up) [kB/frame]."""
    import numpy as np

    k, mb = np.array(samples, dtype=np.float64).T
    late = k >= k[-1] / 4
    if late.sum() < 2:
        return float("nan")
    return 1024 * float(np.polyfit(k[late], mb[late], 1)[0])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", default="convoy")
    ap.add_argument("--short", type=float, default=60.0, help="simulated seconds of the short run")
    ap.add_argument("--long", type=float, default=1200.0, help="simulated seconds of the long run")
    ap.add_argument("--recording", choices=("both", "on", "off"), default="both")
    ap.add_argument("--sample-every", type=int, default=100, help="frames between RSS samples")
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--duration", type=float, help=argparse.SUPPRESS)
    ap.add_argument("--longest", type=float, help=argparse.SUPPRESS)
    ap.add_argument("--record", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        return child(args)

    modes = {"both": (False, True), "on": (True,), "off": (False,)}[args.recording]
    scn = scenario(args.scenario, args.long, args.long)
    print(f"{scn.name}: road {scn.road.length_m / 1000:g} km, {args.short:g} s vs {args.long:g} s at "
          f"{scn.rate_hz:g} Hz, one fresh process per run")
    print(f"\n{'recording':<10}{'run':>8}{'frames':>8}{'peak MB':>9}{'RSS@' + str(args.sample_every):>9}"
          f"{'RSS end':>9}{'kB/frame':>10}{'rrd MB':>8}{'s':>7}")
    verdicts = []
    for record in modes:
        peaks = []
        for duration in (args.short, args.long):
            r = measure(args, duration, record)
            s = r["samples"]
            first = s[1][1] if len(s) > 1 else s[0][1]
            print(f"{'on' if record else 'off':<10}{duration:7g}s{r['frames']:8d}{r['peak_mb']:9.0f}{first:9.0f}"
                  f"{s[-1][1]:9.0f}{growth_kb_per_frame(s):10.1f}{r['rrd_mb']:8.1f}{r['seconds']:7.0f}",
                  flush=True)
            peaks.append(r["peak_mb"])
        ratio = peaks[1] / peaks[0]
        verdicts.append(ratio <= TARGET_RATIO)
        print(f"{'':<10}peak ratio {args.long:g} s / {args.short:g} s = {ratio:.2f}  (target <= {TARGET_RATIO})")
    print("target:", "MET" if all(verdicts) else "NOT MET")


if __name__ == "__main__":
    main()
