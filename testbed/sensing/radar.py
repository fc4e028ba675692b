"""A radar as a sensor of the sensing loop (:data:`RADAR`, registered as ``radar``; settings ``sensor.radar``).

On the ego's centre, looking along its heading: every vehicle whose centre lies within ``range_m`` and the field of
view ``fov_deg`` is detected with probability ``pd`` as z = [range, azimuth, range-rate] plus Gaussian noise
(sigma_r, sigma_az, sigma_rr), range-rate = (p - s).(v - v_s) / |p - s| with s, v_s the ego's position and velocity;
Poisson(``clutter_per_scan``) clutter detections are uniform over [0, range_m] x field of view x +-max_range_rate.
It sees through other vehicles (no occlusion model) [D]. The detections carry their measurement model
(trackers.models.RangeBearingRate at the frame's ego pose), so a tracker takes them alone (``tracker.sensors =
["radar"]``) or after the LiDAR's by a sequential update (``["lidar", "radar"]``).

Data (a table the sensing cache stores): ``z`` (M, 3) [m, rad, m/s], ``truth_id`` (M,) int64 (the vehicle a
detection comes from, -1 for clutter; for scoring only, never given to a tracker). Random stream ``sensor.radar``.
"""
from __future__ import annotations

import math

import numpy as np

from .sensor import Measurements, SensingContext, Sensor


def _wrap(a: np.ndarray) -> np.ndarray:
    return (a + math.pi) % (2.0 * math.pi) - math.pi


def model_of(ctx: SensingContext, truth):
    """The measurement model of the frame (trackers.models.RangeBearingRate): the radar's noise at the ego's pose
    and velocity in ``truth``."""
    from roadtrack.trackers.models import RangeBearingRate  # not at import: importing trackers loads its plug-ins,
    # whose warnings the CLI shows as one line only once its commands run (testbed/cli/main.py)

    spec = ctx.scn.sensor.radar
    pose = truth.ego_pose
    return RangeBearingRate(spec.sigma_r_m, math.radians(spec.sigma_az_deg), spec.sigma_rr_mps,
                            pose=(float(pose[0]), float(pose[1]), float(pose[2])),
                            velocity=(float(truth.velocity[0, 0]), float(truth.velocity[0, 1])))


def in_view(ctx: SensingContext, truth) -> tuple[np.ndarray, np.ndarray]:
    """(in view (K,) bool, exact [range, azimuth, range-rate] (K, 3)) of every vehicle of ``truth`` (the ego, row
    0, never in view)."""
    spec = ctx.scn.sensor.radar
    d = truth.xy - truth.xy[0]
    u = truth.velocity - truth.velocity[0]
    r = np.hypot(d[:, 0], d[:, 1])
    az = _wrap(np.arctan2(d[:, 1], d[:, 0]) - truth.heading[0])
    with np.errstate(invalid="ignore", divide="ignore"):
        rr = np.where(r > 0, (d * u).sum(axis=1) / np.where(r > 0, r, 1.0), 0.0)
    seen = (r <= spec.range_m) & (np.abs(az) <= 0.5 * math.radians(spec.fov_deg)) & (r > 0)
    seen[0] = False
    return seen, np.c_[r, az, rr]


def sense_radar(ctx: SensingContext, truth, rngs: dict) -> dict[str, np.ndarray]:
    """One scan: the detected vehicles' noisy [range, azimuth, range-rate], then the clutter (module docstring)."""
    spec, rng = ctx.scn.sensor.radar, rngs["sensor.radar"]
    seen, exact = in_view(ctx, truth)
    hit = seen & (rng.random(len(seen)) < spec.pd)
    noise = rng.standard_normal((int(hit.sum()), 3)) * [spec.sigma_r_m, math.radians(spec.sigma_az_deg),
                                                         spec.sigma_rr_mps]
    z = exact[hit] + noise
    z[:, 1] = _wrap(z[:, 1])
    n = int(rng.poisson(spec.clutter_per_scan))
    half = 0.5 * math.radians(spec.fov_deg)
    clutter = np.c_[rng.uniform(0.0, spec.range_m, n), rng.uniform(-half, half, n),
                    rng.uniform(-spec.max_range_rate_mps, spec.max_range_rate_mps, n)]
    ids = np.concatenate([np.asarray(truth.ids, dtype=np.int64)[hit], np.full(n, -1, dtype=np.int64)])
    return {"z": np.vstack([z, clutter]).reshape(-1, 3), "truth_id": ids}


def radar_visibility(ctx: SensingContext, truth, data: dict) -> tuple[np.ndarray, np.ndarray]:
    """(detections on each vehicle of ``truth`` (K,) int64, in the field of view and range (K,) bool)."""
    seen, _ = in_view(ctx, truth)
    ids = np.asarray(truth.ids, dtype=np.int64)
    hits = (data["truth_id"][None, :] == ids[:, None]).sum(axis=1).astype(np.int64)
    return hits, seen


def radar_measurements(ctx: SensingContext, truth, data: dict) -> Measurements:
    """The frame's detections with their model; the clutter density is the mean clutter over the measurement
    volume range x field of view x range-rate span [1 / (m rad m/s)], with at least 1e-3 clutter per scan (a
    PDA's clutter density must be > 0; clutter_per_scan = 0 gives the tracker that floor)."""
    spec = ctx.scn.sensor.radar
    volume = spec.range_m * math.radians(spec.fov_deg) * 2.0 * spec.max_range_rate_mps
    return Measurements(np.asarray(data["z"], dtype=np.float64).reshape(-1, 3), model_of(ctx, truth), None, spec.pd,
                        max(spec.clutter_per_scan, 1e-3) / volume)


RADAR = Sensor("radar", sense_radar, radar_visibility, None, measurements=radar_measurements,
               doc="radar: range, azimuth, range-rate of vehicle centres in its field of view, Poisson clutter "
                   "(sensor.radar)")
