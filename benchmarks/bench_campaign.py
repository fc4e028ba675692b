"""Campaign throughput: runs per second on 1 and 2 local workers and on a 2-worker Dask LocalCluster.

    .venv/bin/python benchmarks/bench_campaign.py [--runs 16] [--duration 2.0] [--repeat 3]

A fixed small campaign (cut_in_out shortened to ``--duration`` s, jpda-kf and gnn-kf, ``--runs`` / 2
seeds, scores only) runs on warm workers: every engine is started and warmed up first (two short runs per
worker slot), then the engines take turns, ``--repeat`` times, so the numbers are steady-state
throughput, not process start-up (reported separately), and a drift of the machine's speed hits every
engine alike. Every worker gets one thread and one core (OMP_NUM_THREADS=1 and CPU affinity, which also
holds open3d's TBB scene build; Dask's nanny sets OMP_NUM_THREADS=1 and the engine pins LocalCluster
workers too), so that 1 vs 2 workers measures worker scaling, not open3d's own threads;
``1 worker, <cores> threads`` is shown for reference. The mean wall time of one run per engine tells
contention (runs slower when both cores work) from scheduling overhead (gaps between runs). Prints
runs/s, the best of ``--repeat`` timings, and the speed-up ratios (targets: >= 1.8x from 1 to 2 workers;
Dask within 10 % of the local 2-worker pool), and checks that every engine produced the same numbers.
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("RERUN_ANALYTICS", "0")
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from roadtrack.testbed.campaign import store  # noqa: E402
from roadtrack.testbed.campaign.engine import EngineOptions, make_backend, run_campaign, usable_cores  # noqa: E402
from roadtrack.testbed.campaign.spec import parse_campaign  # noqa: E402

TRACKERS = ["jpda-kf", "gnn-kf"]


def campaign_dict(runs: int, duration: float, name: str = "bench") -> dict:
    return dict(name=name, scenarios=["cut_in_out"], trackers=TRACKERS, seeds=max(1, runs // len(TRACKERS)),
                base_seed=7, overrides={"duration_s": duration})


def start(opts: EngineOptions):
    """A started engine, warmed up with two short runs per worker slot; (backend, seconds it took)."""
    t0 = time.perf_counter()
    backend = make_backend(opts)
    warm = parse_campaign(campaign_dict(2 * backend.slots, 0.3, "warm-up"))
    with tempfile.TemporaryDirectory() as tmp:
        run_campaign(warm, Path(tmp), quiet=True, backend=backend)
    return backend, time.perf_counter() - t0


def timed(backend, campaign) -> tuple[float, object]:
    """(runs/s, results table) of one execution of ``campaign`` on a warm ``backend``."""
    with tempfile.TemporaryDirectory() as tmp:
        t = time.perf_counter()
        outcome = run_campaign(campaign, Path(tmp), quiet=True, backend=backend)
        elapsed = time.perf_counter() - t
        assert outcome.complete and outcome.failed == 0, outcome
        return campaign.n_runs / elapsed, store.load_results(tmp)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--runs", type=int, default=16)
    p.add_argument("--duration", type=float, default=2.0)
    p.add_argument("--repeat", type=int, default=3)
    args = p.parse_args(argv)
    cores = usable_cores()
    engines = {
        "local, 1 worker": EngineOptions(workers=1, threads=1),
        "local, 2 workers": EngineOptions(workers=2, threads=1),
        "dask LocalCluster, 2 workers": EngineOptions(dask_local=2),
        f"local, 1 worker, {cores} threads": EngineOptions(workers=1, threads=cores),
    }
    print(f"{args.runs} runs of cut_in_out, {args.duration} s each, trackers {TRACKERS}, {cores} usable cores, "
          f"best of {args.repeat}")
    campaign = parse_campaign(campaign_dict(args.runs, args.duration))
    backends, rates, tables = {}, {name: [] for name in engines}, {}
    try:
        for name, opts in engines.items():
            backends[name], startup = start(opts)
            print(f"  started {name:<32} in {startup:4.1f} s ({backends[name].description})", flush=True)
        for rep in range(args.repeat):  # interleaved, so that a drift of the machine hits every engine
            for name, backend in backends.items():
                r, tables[name] = timed(backend, campaign)
                rates[name].append(r)
    finally:
        for backend in backends.values():
            backend.close(abandon=False)
    rate = {name: max(r) for name, r in rates.items()}
    for name in engines:
        print(f"  {name:<32} {rate[name]:6.3f} runs/s  (all: {', '.join(f'{r:.3f}' for r in rates[name])}; "
              f"mean wall time of a run {tables[name]['wall_s'].mean():.3f} s)")
    scaling = rate["local, 2 workers"] / rate["local, 1 worker"]
    dask = rate["dask LocalCluster, 2 workers"] / rate["local, 2 workers"]
    print(f"speed-up 2 vs 1 local worker: {scaling:.2f}x (target >= 1.8)")
    print(f"Dask LocalCluster vs local pool, 2 workers: {dask:.2f}x (target >= 0.90)")

    keep = None
    for name, table in tables.items():
        cols = [c for c in table.columns if c not in store.timing_columns(table.columns)
                and c != store.SERIES_COLUMN]
        t = table[cols].sort_values("run_id").reset_index(drop=True)
        if keep is None:
            keep = t
        elif not t.equals(keep):
            print(f"MISMATCH: {name} gave different numbers")
            return 1
    print("all engines gave identical results")
    return 0


if __name__ == "__main__":
    sys.exit(main())
