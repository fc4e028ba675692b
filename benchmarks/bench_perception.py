"""Perception cost per frame and stage with 10, 30 and 60 vehicles in view, against the 100 ms of a 10 Hz scan.

    .venv/bin/python benchmarks/bench_perception.py [--frames 40] [--cores 1] [--loop-seconds 20]

Part 1, the perception stack on synthetic motorway scenes (8 lanes, guard rails, posts and trees as in the
highway benchmark, N vehicles within 60 m of the sensor car): ms per frame for ray casting, ground
segmentation, clustering and the rest of perceive() (selection, merging, box fits), for the HDL-32E and
the 128-beam profile (vls128), plus the occlusion P_D of N predicted positions. Target: HDL-32E
perception (ray cast, ground, clusters, centres) at 30 vehicles <= 10 ms per frame on one core.

Part 2, the whole loop (traffic, LiDAR, perception, tracker; no recording) through ``run_scenario`` on the
highway benchmark with its traffic density raised until about 30 vehicles are within the sensor's range,
printed as a multiple of real time. Target: >= 10x real time.
All numbers are medians measured in this one run, pinned to --cores cores.
"""
from __future__ import annotations

import os
import sys


def _pin(argv: list[str]) -> None:
    """Pin the process to the first --cores cores *before* numpy, BLAS and open3d start their threads, and
    size their thread pools to match: threads started earlier keep running on the other cores, and more
    pool threads than cores spin against each other (a 10x slower least-squares solve on one core)."""
    cores = 1
    for i, a in enumerate(argv):
        if a == "--cores" and i + 1 < len(argv):
            cores = int(argv[i + 1])
        elif a.startswith("--cores="):
            cores = int(a.split("=", 1)[1])
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ[var] = str(cores)
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, set(sorted(os.sched_getaffinity(0))[:cores]))


if __name__ == "__main__":  # run as a script: the checkout first on sys.path (the benchmarks folder after it)
    _here = os.path.dirname(os.path.abspath(__file__))
    sys.path[:] = [os.path.dirname(_here)] + [p for p in sys.path if os.path.abspath(p or ".") != _here]
    _pin(sys.argv[1:])

import argparse
import statistics
import time

import numpy as np

from roadtrack import sensors
from roadtrack.testbed.world.roadside import roadside_boxes
from roadtrack.testbed.pipeline.run import run_scenario
from roadtrack.testbed.scenario.spec import RoadsideSpec, load_scenario

BUDGET_MS = 100.0
LANE = 4.0


def motorway_scene(n_vehicles: int, rng: np.random.Generator):
    """Vehicle boxes (n, 7) within 60 m of a sensor at the origin on an 8-lane motorway (lanes y = 0..28 m,
    the sensor car in lane 1), roadside boxes along both edges, and the road map."""
    lane_y = np.array([0, 1, 2, 3, 5, 6, 7, 8]) * LANE  # a 4 m median between lanes 3 and 5
    boxes = []
    while len(boxes) < n_vehicles:
        y = lane_y[rng.integers(len(lane_y))]
        x = rng.uniform(-58.0, 58.0)
        if abs(y - LANE) < 1 and abs(x) < 6:
            continue  # the sensor car
        truck = rng.random() < 0.2
        L, W, H = (rng.uniform(12, 18), 2.5, 3.8) if truck else (rng.uniform(4.2, 5.0), 1.85, 1.55)
        if any(abs(b[1] - y) < 1 and abs(b[0] - x) < (b[2] + L) / 2 + 1.0 for b in boxes):
            continue
        boxes.append([x, y, L, W, H, 0.0, 0.0])
    xs = np.arange(-150.0, 150.0, 1.0)
    edges = [(np.column_stack([xs, np.full(len(xs), -2.0)]), np.tile([0.0, -1.0], (len(xs), 1))),
             (np.column_stack([xs, np.full(len(xs), 8 * LANE + 2.0)]), np.tile([0.0, 1.0], (len(xs), 1)))]
    static = roadside_boxes(edges, RoadsideSpec(), rng)
    centres = np.concatenate([np.column_stack([xs, np.full(len(xs), y)]) for y in lane_y])
    road = sensors.RoadMap(centres, np.zeros(len(centres)), np.full(len(centres), LANE / 2))
    return np.asarray(boxes), static, road


def time_stack(lidar: sensors.LidarConfig, n: int, frames: int, seed: int = 0) -> dict[str, float]:
    rng = np.random.default_rng(seed)
    cfg = sensors.PerceptionConfig()
    occ = sensors.OcclusionConfig(max_range_m=lidar.max_range_m)
    t: dict[str, list[float]] = {k: [] for k in ("ray casting", "ground", "clustering", "selection + fits", "perception",
                                                 "occlusion P_D")}
    points = []
    for f in range(frames):
        cars, static, road = motorway_scene(n, rng)
        boxes = np.vstack([cars, static])
        ids = np.concatenate([np.arange(len(cars)), np.full(len(static), -1)])
        t0 = time.perf_counter()
        s = sensors.scan(lidar, np.array([0.0, LANE, 0.0]), boxes, ids, rng)
        t1 = time.perf_counter()
        g = sensors.segment_ground(s.points, cfg.ground, s.origin)
        t2 = time.perf_counter()
        sensors.cluster(s.points[~g & (s.points[:, 2] <= cfg.max_height_m)], cfg.cluster)
        t3 = time.perf_counter()
        sensors.perceive(s, cfg, road)
        t4 = time.perf_counter()
        sensors.detection_probability(s, cars[:, :2], occ)
        t5 = time.perf_counter()
        t["ray casting"].append(t1 - t0)
        t["ground"].append(t2 - t1)
        t["clustering"].append(t3 - t2)
        t["selection + fits"].append(max((t4 - t3) - (t2 - t1) - (t3 - t2), 0.0))
        t["occlusion P_D"].append(t5 - t4)
        t["perception"].append((t1 - t0) + (t4 - t3))  # scan + perceive (ground, clusters, fits) of this frame
        points.append(len(s.points))
    out = {k: 1000 * statistics.median(v) for k, v in t.items()}
    out["points"] = float(np.median(points))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=40, help="scenes per configuration")
    ap.add_argument("--cores", type=int, default=1, help="pin the process to this many cores")
    ap.add_argument("--loop-seconds", type=float, default=20.0, help="simulated seconds of the whole-loop run "
                    "(0 = skip part 2)")
    args = ap.parse_args()
    if hasattr(os, "sched_setaffinity"):  # _pin did it before the imports; this is for an import of main()
        cores = set(sorted(os.sched_getaffinity(0))[: args.cores])
        for tid in os.listdir("/proc/self/task") if os.path.isdir("/proc/self/task") else ["0"]:
            os.sched_setaffinity(int(tid), cores)
    print(f"pinned to {len(os.sched_getaffinity(0)) if hasattr(os, 'sched_getaffinity') else '?'} core(s); "
          f"medians over {args.frames} scenes\n")
    time_stack(sensors.LidarConfig(), 5, 3)  # warm imports and caches
    stages = ("ray casting", "ground", "clustering", "selection + fits")
    print(f"{'sensor':<8}{'vehicles':>9}{'points':>8}" + "".join(f"{s:>18}" for s in stages) +
          f"{'perception':>12}{'of 100 ms':>10}{'occl. P_D':>11}")
    verdict = None
    for preset in ("hdl32e", "vls128"):
        lidar = sensors.LidarConfig(preset=preset)
        time_stack(lidar, 5, 2)
        for n in (10, 30, 60):
            r = time_stack(lidar, n, args.frames)
            total = r["perception"]  # median of the per-frame totals (not the sum of the stage medians)
            print(f"{preset:<8}{n:>9}{r['points']:>8.0f}" + "".join(f"{r[s]:>18.2f}" for s in stages) +
                  f"{total:>12.2f}{total / BUDGET_MS:>10.1%}{r['occlusion P_D']:>11.2f}")
            if preset == "hdl32e" and n == 30:
                verdict = total
    print(f"\ntarget: HDL-32E perception at 30 vehicles <= 10 ms/frame: {verdict:.2f} ms -> "
          f"{'MET' if verdict <= 10.0 else 'NOT MET'}")

    if args.loop_seconds > 0:
        over = {"duration_s": args.loop_seconds, "traffic.density_per_km_lane": 27.0}
        run_scenario(load_scenario("highway_benchmark", {**over, "duration_s": 1.0}), record=False)
        scn = load_scenario("highway_benchmark", over)
        res = run_scenario(scn, record=False)
        tr = res.tables["truth"]
        frame, ego = tr.array("frame"), tr.array("is_ego")
        in_range = tr.array("in_range") & ~ego
        per_frame = np.bincount(frame[in_range], minlength=res.n_frames)
        p = res.timings_ms
        loop = sum(p[k] for k in ("simulation", "raycast", "perception", "tracking"))
        print(f"\nwhole loop, highway_benchmark at 27 vehicles/km/lane, {res.n_frames} frames, "
              f"{per_frame.mean():.1f} vehicles within {scn.sensor.lidar.max_range_m:.0f} m on average "
              f"(max {per_frame.max()}):")
        print("  " + ", ".join(f"{k} {v:.2f}" for k, v in p.items() if k != "recording") + " ms/frame")
        print(f"  loop {loop:.2f} ms/frame -> {BUDGET_MS / loop:.1f}x real time "
              f"(target >= 10x: {'MET' if BUDGET_MS / loop >= 10 else 'NOT MET'})")


if __name__ == "__main__":
    main()
