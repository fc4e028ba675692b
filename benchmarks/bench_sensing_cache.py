"""Sense once, track many: a campaign's wall time with and without the sensing cache, and a tracker-only run of the
full highway benchmark from a warm cache, measured in one run on this machine.

    .venv/bin/python benchmarks/bench_sensing_cache.py [--campaign campaigns/named_trackers_highway.toml]
                                                 [--workers 2] [--skip-full] [--skip-full-stack]

1. The campaign (default: the papers' 13 named trackers x 2 seeds x 60 s of the highway benchmark) runs twice into
   fresh folders, ``--no-sensing-cache`` first, then with the cache (each traffic sensed once into the folder's
   sensing/, every tracker run on it). Prints both wall times, their ratio (target >= 4x) and checks that both
   gave the same results to the last digit. The shipped campaign pins the thesis's plain perception pipeline
   (cheap sensing, about 17 ms a frame); then the same campaign runs with the full stack (the default pipeline,
   about 42 ms a frame, whose sensing cost the target was set on), unless ``--skip-full-stack``.
2. The full 427 s highway benchmark is sensed once into a cache (timed), then jpda-kf runs on it alone (target:
   <= 60 s), and the cache entry's size on disk is printed.
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

import pandas as pd  # noqa: E402

from roadtrack.testbed.campaign import store  # noqa: E402
from roadtrack.testbed.campaign.engine import EngineOptions, run_campaign  # noqa: E402
from roadtrack.testbed.campaign.spec import load_campaign  # noqa: E402
from roadtrack.testbed.pipeline.run import run_scenario  # noqa: E402
from roadtrack.testbed.scenario.spec import load_scenario  # noqa: E402
from roadtrack.testbed.sensing.cache import SensingCache  # noqa: E402

REPO = Path(__file__).resolve().parent.parent


def _campaign_time(path: Path, out: Path, workers: int, cache: bool) -> tuple[float, pd.DataFrame]:
    campaign = load_campaign(path)
    t0 = time.perf_counter()
    outcome = run_campaign(campaign, out, EngineOptions(workers=workers, sensing_cache=cache), quiet=True)
    wall = time.perf_counter() - t0
    if outcome.failed:
        raise SystemExit(f"{outcome.failed} runs failed in {out}")
    return wall, pd.read_parquet(out / store.RESULTS_FILE)


def _same_results(a: pd.DataFrame, b: pd.DataFrame) -> bool:
    drop = [c for c in a.columns if c in store.TIMING_COLUMNS or c.startswith("ms_") or c == store.SERIES_COLUMN]
    a = a.drop(columns=drop).sort_values("run_id").reset_index(drop=True)
    b = b.drop(columns=drop).sort_values("run_id").reset_index(drop=True)
    try:
        pd.testing.assert_frame_equal(a, b, check_exact=True)
    except AssertionError as err:
        print(f"  results differ: {str(err).splitlines()[0]}")
        return False
    return True


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--campaign", default=str(REPO / "campaigns" / "named_trackers_highway.toml"))
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--skip-full", action="store_true", help="skip the full 427 s benchmark part")
    p.add_argument("--skip-full-stack", action="store_true", help="skip the campaign with the full perception stack")
    args = p.parse_args()
    with tempfile.TemporaryDirectory(prefix="sensing-cache-bench-") as tmp:
        tmp = Path(tmp)
        variants = [("as shipped", Path(args.campaign))]
        if not args.skip_full_stack:
            text = Path(args.campaign).read_text(encoding="utf-8")
            full = tmp / "full_stack.toml"
            full.write_text("\n".join(line for line in text.splitlines()
                                      if not line.strip().startswith('"sensor.pipeline"')) + "\n", encoding="utf-8")
            variants.append(("with the full perception stack", full))
        for i, (what, path) in enumerate(variants):
            print(f"1{'ab'[i]}. campaign {Path(args.campaign).stem} {what}, on {args.workers} workers")
            t_off, r_off = _campaign_time(path, tmp / f"off{i}", args.workers, cache=False)
            print(f"   without the sensing cache: {t_off:7.1f} s ({len(r_off)} runs)")
            t_on, r_on = _campaign_time(path, tmp / f"on{i}", args.workers, cache=True)
            size = SensingCache(tmp / f"on{i}" / store.SENSING_DIR).size_bytes()
            ms = {c: r_on[c].sum() for c in r_on.columns if c.startswith("ms_")}
            print(f"   with the sensing cache:    {t_on:7.1f} s (cache {size / 1e6:.1f} MB)")
            print(f"   ratio {t_off / t_on:.2f}x (target >= 4x); same results: {_same_results(r_off, r_on)}")
            if "ms_tracking" in ms and "n_frames" in r_on.columns:
                track_s = float((r_on["ms_tracking"] * r_on["n_frames"]).sum()) / 1000.0
                print(f"   of which tracking alone: {track_s:.1f} s of CPU over all runs "
                      f"({track_s / args.workers:.1f} s of wall time on {args.workers} workers at best)")
        if args.skip_full:
            return 0
        print("2. the full highway benchmark (427 s, 4275 frames)")
        scn = load_scenario("highway_benchmark")
        cache = tmp / "full"
        t0 = time.perf_counter()
        run_scenario(scn, record=False, tracker="jpda-kf", sensing_cache=cache)
        t_sense = time.perf_counter() - t0
        t0 = time.perf_counter()
        res = run_scenario(scn, record=False, tracker="jpda-kf", sensing_cache=cache)
        t_track = time.perf_counter() - t0
        size = SensingCache(cache).size_bytes(scn)
        print(f"   sensing and tracking, storing the cache: {t_sense:7.1f} s")
        print(f"   jpda-kf from the warm cache:             {t_track:7.1f} s (target <= 60 s; "
              f"{1000 * t_track / res.n_frames:.1f} ms per frame, tracking {res.timings_ms['tracking']:.1f})")
        print(f"   cache entry: {size / 1e6:.1f} MB ({size / res.n_frames / 1e3:.1f} kB per frame)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
