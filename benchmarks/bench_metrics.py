"""Time testbed.scoring.mot_metrics on a run-sized case: 200 frames, 5 truths and 10 confirmed tracks per frame.

    .venv/bin/python benchmarks/bench_metrics.py [--frames 200] [--truths 5] [--tracks 10] [--repeats 20]

Prints the one-off TrackEval import + construction time and the median / min / max of mot_metrics.
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from roadtrack.testbed.scoring.mot_metrics import trackeval_metrics, mot_metrics


def make_case(n_frames: int, n_truth: int, n_tracks: int, seed: int = 0):
    """Truth on straight lanes at 25 m/s (10 Hz); one noisy track (sigma 0.5 m) per truth, the rest clutter."""
    rng = np.random.default_rng(seed)
    k = np.arange(n_frames)
    g_xy = np.stack([2.5 * k[:, None] + 30.0 * np.arange(n_truth), np.broadcast_to(4.0 * (np.arange(n_truth) % 3),
                     (n_frames, n_truth))], axis=-1)                                       # (F, G, 2)
    n_on = min(n_truth, n_tracks)
    t_xy = np.concatenate([g_xy[:, :n_on] + rng.normal(0.0, 0.5, (n_frames, n_on, 2)),
                           g_xy[:, :1] + rng.uniform(-40.0, 40.0, (n_frames, n_tracks - n_on, 2))], axis=1)
    truth = {"frame": np.repeat(k, n_truth), "vehicle_id": np.tile(np.arange(n_truth), n_frames),
             "xy": g_xy.reshape(-1, 2)}
    tracks = {"frame": np.repeat(k, n_tracks), "track_id": np.tile(np.arange(n_tracks), n_frames),
              "xy": t_xy.reshape(-1, 2)}
    return truth, tracks


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=200)
    ap.add_argument("--truths", type=int, default=5)
    ap.add_argument("--tracks", type=int, default=10)
    ap.add_argument("--repeats", type=int, default=20)
    args = ap.parse_args()

    t0 = time.perf_counter()
    trackeval_metrics()
    print(f"TrackEval import + construction (once per process): {1e3 * (time.perf_counter() - t0):.0f} ms")

    truth, tracks = make_case(args.frames, args.truths, args.tracks)
    times = []
    for _ in range(args.repeats):
        t0 = time.perf_counter()
        res = mot_metrics(truth, tracks, args.frames)
        times.append(time.perf_counter() - t0)
    ms = 1e3 * np.array(times)
    print(f"mot_metrics {args.frames} frames x {args.truths} truths x {args.tracks} tracks: "
          f"median {np.median(ms):.1f} ms, min {ms.min():.1f} ms, max {ms.max():.1f} ms ({args.repeats} runs)")
    print("  " + ", ".join(f"{k}={v:.4g}" for k, v in res.items()))


if __name__ == "__main__":
    main()
