"""``testbed export RUN --format kitti``: a run as a KITTI-tracking sequence (docs/formats.md, field by field).

    OUT/velodyne/0000/NNNNNN.bin   float32 x, y, z, intensity per point, velodyne frame
    OUT/label_02/0000.txt          KITTI's 17 label columns per vehicle and frame (every vehicle but the ego)
    OUT/calib/0000.txt             P0..P3, R_rect, Tr_velo_cam, Tr_imu_velo
    OUT/oxts/0000.txt              the ego's 30 oxts values per frame
    OUT/roadtrack_scenario.json    the run's scenario (values only): what ``testbed replay`` reads besides KITTI's

The run folder holds no point clouds, so the scans are sensed again from the scenario in scores.json: a run is
deterministic from its scenario and seed (README), and the export checks the re-simulated truth against the
run's truth table, refusing (one line) a run it cannot reproduce (an ego driven by a user's ``--policy``, or
a run made by other code). The conventions (frames, units, transforms, geodetic origin) are those of
testbed.sensing.kitti.

    write(run, path) -> Path          run: testbed.pipeline.runfolder.RunData; path: the folder to write
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from roadtrack import sensors
from roadtrack.sensors.occlusion import visibility as lidar_visibility

from ..common.jsonio import json_text
from ..common.safe_io import make_folder, write_bytes, write_text
from ..config import ConfigError, to_dict
from ..sensing import frame_scan, pd_scan, rng_streams, sensing_setup
from ..sensing import kitti as k

TRUTH_TOLERANCE_M = 1e-6
"""Largest difference [m] between the re-simulated and the recorded truth positions of a reproducible run."""


def write(run, path: str | Path) -> Path:
    """Write ``run`` (RunData) as a KITTI-tracking sequence into the folder ``path`` (created; each file written
    atomically, never through a planted symbolic link)."""
    scn = run.scenario
    if scn is None:
        raise ConfigError(str(run.folder), "no scenario in scores.json: the scans cannot be sensed again")
    if run.incomplete is not None:
        raise ConfigError(str(run.folder), "the run is INCOMPLETE; export a finished run")
    out = make_folder(path, "--out")
    dirs = {name: make_folder(out / name / (k.SEQUENCE if name == "velodyne" else ""))
            for name in ("velodyne", "label_02", "calib", "oxts")}
    truth = run.truth.sort_values(["frame", "is_ego"], ascending=[True, False], kind="stable")
    n = run.n_frames
    frames = {f: g for f, g in truth.groupby("frame", sort=True)}
    if sorted(frames) != list(range(n)):
        raise ConfigError(str(run.folder), f"truth.parquet does not hold frames 0..{n - 1}")
    lidar = scn.sensor.lidar
    h = lidar.mount_height_m
    occ_cfg = sensors.OcclusionConfig.from_lidar(lidar, min_points=scn.sensor.perception.cluster.min_points)
    ego = truth[truth["is_ego"]].set_index("frame").sort_index()
    labels = []
    for f, scan in _scans(scn, frames):
        pose = np.array([ego.at[f, "x"], ego.at[f, "y"], ego.at[f, "heading"]])
        velo = k.to_velo(scan.points, pose, h).astype("<f4")
        data = np.column_stack([velo, np.zeros((len(velo), 1), "<f4")]).astype("<f4")
        write_bytes(dirs["velodyne"] / f"{f:06d}.bin", data.tobytes())
        labels.extend(_label_lines(frames[f], f, pose, h, pd_scan(scan, scan.source == sensors.GROUND), occ_cfg))
    seq = k.SEQUENCE
    write_text(dirs["label_02"] / f"{seq}.txt", "".join(labels))
    write_text(dirs["calib"] / f"{seq}.txt", k.calib_text(h))
    write_text(dirs["oxts"] / f"{seq}.txt", oxts_text(ego, scn.dt))
    write_text(out / k.SCENARIO_FILE, json_text(to_dict(scn), indent=2) + "\n")
    return out


def _scans(scn, frames: dict[int, pd.DataFrame]):
    """(frame, Scan) of the run, sensed again (testbed.sensing.frame_scan, the live run's scan with its outages);
    ConfigError when the re-simulated truth is not the run's."""
    rngs = rng_streams(scn.seed)
    sim, static, _road = sensing_setup(scn, rngs)
    try:
        for truth in sim.frames():
            f = truth.frame
            if f not in frames:
                break
            rec = frames[f]
            same = (len(rec) == len(truth.ids) and np.array_equal(rec["vehicle_id"].to_numpy(), truth.ids)
                    and np.abs(rec[["x", "y"]].to_numpy() - truth.xy).max(initial=0.0) <= TRUTH_TOLERANCE_M)
            if not same:
                raise ConfigError("export", f"the scenario in scores.json does not reproduce the run's traffic "
                                            f"(frame {f}): a run whose ego a --policy drove, or made by other code, "
                                            "cannot be sensed again")
            yield f, frame_scan(truth, static, scn, rngs)[1]
    finally:
        close = getattr(sim, "close", None)
        if callable(close):
            close()


def _label_lines(rows: pd.DataFrame, f: int, pose: np.ndarray, h: float, bare, occ_cfg) -> list[str]:
    """KITTI label lines of frame ``f``: every vehicle of ``rows`` (the frame's truth) but the ego."""
    cars = rows[~rows["is_ego"].to_numpy()]
    if cars.empty:
        return []
    xy = cars[["x", "y"]].to_numpy(np.float64)
    heading = cars["heading"].to_numpy(np.float64)
    size = cars[["length", "width", "height"]].to_numpy(np.float64)
    occluded = occlusion_levels(bare, xy, heading, size, occ_cfg)
    bottom = k.to_velo(np.column_stack([xy, np.zeros(len(xy))]), pose, h)
    loc = k.velo_to_cam(bottom)
    ry = k.wrap(-(heading - pose[2]) - np.pi / 2)
    alpha = k.wrap(ry - np.arctan2(loc[:, 0], loc[:, 2]))
    lines = []
    for i, vid in enumerate(cars["vehicle_id"].to_numpy()):
        length, width, height = size[i]
        corners = k.box_corners_cam(loc[i], np.array([height, width, length]), float(ry[i]))
        box, truncated = k.image_box(corners)
        values = (truncated, occluded[i], alpha[i], *box, height, width, length, *loc[i], ry[i])
        lines.append(f"{f} {int(vid)} {k.vehicle_type(length)} {values[0]:.6f} {int(values[1])} "
                     + " ".join(f"{v:.6f}" for v in values[2:]) + "\n")
    return lines


def occlusion_levels(bare: sensors.Scan, xy: np.ndarray, heading: np.ndarray, size: np.ndarray,
                     cfg: sensors.OcclusionConfig) -> np.ndarray:
    """(K,) KITTI occlusion 0-3 of vehicles (xy (K, 2) [m], heading (K,), size (K, 3) length, width, height) from
    the visible share of their width in the scan's range image without the road's returns
    (sensors.occlusion.visibility, each at its true size): >= VISIBLE_FULLY 0, >= VISIBLE_PARTLY 1, else 2;
    3 where no ray of the sensor would reach the vehicle (beyond its range, or below its lowest beams)."""
    out = np.full(len(xy), 3, np.int64)
    if bare.ranges.size == 0:  # the sensor was off
        return out
    for i in range(len(xy)):
        vis = lidar_visibility(bare, xy[i : i + 1], cfg, size_m=tuple(size[i]), heading=heading[i : i + 1])
        if vis.columns[0] > 0:
            v = float(vis.visible_fraction[0])
            out[i] = 0 if v >= k.VISIBLE_FULLY else 1 if v >= k.VISIBLE_PARTLY else 2
    return out


def oxts_text(ego: pd.DataFrame, dt: float) -> str:
    """The oxts lines of the ego's truth rows (indexed by frame): position (:func:`k.geodetic`), attitude (roll and
    pitch 0: the road is flat), velocity (north, east, forward, left, up), acceleration and angular rate (by
    differences of the velocity and heading over ``dt``, 0 at the first frame; x, y, z = forward, left, up),
    accuracies 0, navstat 4, numsats 0, posmode / velmode / orimode 0."""
    xy = ego[["x", "y"]].to_numpy(np.float64)
    lat, lon, _scale = k.geodetic(xy)
    yaw = ego["heading"].to_numpy(np.float64)
    v = ego[["vx", "vy"]].to_numpy(np.float64)
    c, s = np.cos(yaw), np.sin(yaw)
    vf, vl = c * v[:, 0] + s * v[:, 1], -s * v[:, 0] + c * v[:, 1]
    acc = np.vstack([np.zeros((1, 2)), np.diff(v, axis=0) / dt]) if len(v) else np.zeros((0, 2))
    af, al = c * acc[:, 0] + s * acc[:, 1], -s * acc[:, 0] + c * acc[:, 1]
    wz = np.r_[0.0, k.wrap(np.diff(yaw)) / dt] if len(yaw) else np.zeros(0)
    lines = []
    for i in range(len(xy)):
        row = (lat[i], lon[i], k.ALT0, 0.0, 0.0, float(k.wrap(yaw[i])), v[i, 1], v[i, 0], vf[i], vl[i], 0.0,
               af[i], al[i], 0.0, af[i], al[i], 0.0, 0.0, 0.0, wz[i], 0.0, 0.0, wz[i], 0.0, 0.0)
        lines.append(" ".join(repr(float(x)) for x in row) + " 4 0 0 0 0\n")
    return "".join(lines)

