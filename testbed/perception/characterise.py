"""Characterisation of the perception stack on a scenario: what the trackers are handed, measured against truth.

``characterise(scn)`` runs the scenario's traffic, LiDAR and perception (no tracker) and measures, frame by
frame, against the scan's per-point truth labels:

* ground segmentation precision and recall (truth: the ray hit the road plane);
* detection probability P_D of the vehicles within the sensor's range, by range and by the visible fraction
  of their silhouette (sensors/occlusion.py at the true position); a vehicle is detected when a detection's
  points are mostly its own (``Detections.provenance``);
* centre error of the reported centre (the box fit) and of the cluster centroid against the true centre,
  by range and by view angle (0 deg: seen end-on, 90 deg: seen from the side), as bias (mean error along
  the line of sight) and spread (RMS about the mean);
* split rate (a vehicle giving more than one detection) and merge rate (a detection holding the points of
  two vehicles), and the merge rate against the bumper-to-bumper gap of two cars from a synthetic sweep;
* clutter: detections not from a vehicle, per frame (the thesis's estimate: average clutter objects per
  frame) and per m^2 of the sensor's disk and of the road map within range;
* measurement noise: the box centre's error along and across the line of sight, and the calibration of
  the per-detection covariance R (mean of e' R^-1 e; 2 when calibrated).

``ablation(scn)`` runs the tracker with each static-object method switched off in turn and counts the false
tracks each removes. ``write_report`` writes the markdown and PNG plots; ``measured_settings`` gives the
tracker keys (P_D, clutter density, sigma_w) the measurements support.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from roadtrack import sensors
from roadtrack.sensors.occlusion import visibility as occlusion_visibility

from ..scenario.spec import Scenario

RANGE_BINS = np.arange(0.0, 75.0, 5.0)  # [m]
VIEW_BINS = np.arange(0.0, 91.0, 15.0)  # [deg]
VISIBLE_BINS = np.array([0.0, 0.05, 0.2, 0.4, 0.6, 0.8, 1.0001])
GAPS_M = (0.25, 0.5, 1.0, 1.5, 2.0, 3.0, 5.0, 7.0, 10.0, 15.0, 20.0)
MIN_SHARE = 0.1  # a detection holds a second vehicle when >= 10 % of its points (and >= 5) are that vehicle's


@dataclass
class Characterisation:
    """Per vehicle-frame and per detection records of a characterisation run (numpy columns)."""

    scenario: str
    n_frames: int
    max_range_m: float
    road_area_m2: float  # mean area of the road map within range [m^2]
    ground_tp: int = 0
    ground_fp: int = 0
    ground_fn: int = 0
    vehicles: dict[str, np.ndarray] = field(default_factory=dict)  # per vehicle-frame in range
    detections: dict[str, np.ndarray] = field(default_factory=dict)  # per vehicle detection
    clutter_per_frame: np.ndarray = field(default_factory=lambda: np.zeros(0))
    merge_curve: dict[float, float] = field(default_factory=dict)  # gap [m] -> merge rate
    rejected: dict[str, int] = field(default_factory=dict)  # selection test -> clusters rejected

    # ------------------------------------------------------------------ summaries
    @property
    def ground_precision(self) -> float:
        return self.ground_tp / max(self.ground_tp + self.ground_fp, 1)

    @property
    def ground_recall(self) -> float:
        return self.ground_tp / max(self.ground_tp + self.ground_fn, 1)

    def pd_by(self, key: str, bins: np.ndarray, where: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """P_D (B,) and counts (B,) of the vehicle-frames binned by ``vehicles[key]``."""
        v = self.vehicles
        sel = np.ones(len(v["detected"]), bool) if where is None else where
        idx = np.digitize(v[key][sel], bins) - 1
        det = v["detected"][sel]
        n = np.bincount(idx.clip(0, len(bins) - 2), minlength=len(bins) - 1)[: len(bins) - 1]
        k = np.bincount(idx.clip(0, len(bins) - 2), weights=det, minlength=len(bins) - 1)[: len(bins) - 1]
        with np.errstate(invalid="ignore", divide="ignore"):
            return k / n, n

    def centre_error_by(self, key: str, bins: np.ndarray, which: str) -> dict[str, np.ndarray]:
        """Bias (mean error along the line of sight), spread (RMS about the mean error vector) and count per
        bin of ``detections[key]``, for ``which`` = "box" (the reported centre) or "centroid"."""
        d = self.detections
        e = d[f"err_{which}"]  # (D, 2) error, world [m]
        los = d["los"]  # (D, 2) unit line of sight
        along = np.einsum("ij,ij->i", e, los)
        idx = np.digitize(d[key], bins) - 1
        B = len(bins) - 1
        bias, spread, count = np.full(B, np.nan), np.full(B, np.nan), np.zeros(B, np.int64)
        for b in range(B):
            s = idx == b
            count[b] = int(s.sum())
            if count[b] >= 3:
                bias[b] = float(along[s].mean())
                spread[b] = float(np.sqrt(np.mean(np.sum((e[s] - e[s].mean(axis=0)) ** 2, axis=1))))
        return dict(bias=bias, spread=spread, count=count)

    def summary(self) -> dict[str, float]:
        """The headline numbers (JSON-able)."""
        v, d = self.vehicles, self.detections
        visible = v["visible"] >= 0.5
        n_det = len(d.get("vehicle_id", ()))
        clutter = self.clutter_per_frame
        disk = math.pi * self.max_range_m ** 2
        err = d["err_box"] if n_det else np.zeros((0, 2))
        los = d["los"] if n_det else np.zeros((0, 2))
        along = np.einsum("ij,ij->i", err, los) if n_det else np.zeros(0)
        across = (err[:, 0] * los[:, 1] - err[:, 1] * los[:, 0]) if n_det else np.zeros(0)
        nees = d["nees"] if n_det else np.zeros(0)
        return dict(
            frames=self.n_frames,
            ground_precision=self.ground_precision, ground_recall=self.ground_recall,
            pd_in_range=float(v["detected"].mean()) if len(v["detected"]) else float("nan"),
            pd_visible=float(v["detected"][visible].mean()) if visible.any() else float("nan"),
            pd_occluded=float(v["detected"][~visible].mean()) if (~visible).any() else float("nan"),
            vehicle_frames=int(len(v["detected"])),
            split_rate=float(np.mean(v["n_dets"][v["detected"]] > 1)) if v["detected"].any() else float("nan"),
            merge_rate=float(np.mean(d["merged"])) if n_det else float("nan"),
            clutter_per_frame=float(clutter.mean()) if len(clutter) else float("nan"),
            clutter_per_m2_disk=float(clutter.mean() / disk) if len(clutter) else float("nan"),
            clutter_per_m2_road=float(clutter.mean() / self.road_area_m2) if len(clutter) and self.road_area_m2 > 0
            else float("nan"),
            centre_rmse_box_m=float(np.sqrt(np.mean(np.sum(err ** 2, axis=1)))) if n_det else float("nan"),
            centre_rmse_centroid_m=float(np.sqrt(np.mean(np.sum(d["err_centroid"] ** 2, axis=1)))) if n_det
            else float("nan"),
            noise_along_std_m=float(np.std(along)) if n_det else float("nan"),
            noise_across_std_m=float(np.std(across)) if n_det else float("nan"),
            noise_along_bias_m=float(np.mean(along)) if n_det else float("nan"),
            r_nees_mean=float(np.mean(nees)) if n_det else float("nan"),
        )


def _frames(scn: Scenario, on_frame: Callable[[int, int], None] | None):
    """(truth, scan, perception result, road map) per frame of ``scn``'s traffic, LiDAR and perception."""
    from ..sensing import rng_streams, sense_simulation, sensing_setup

    rngs = rng_streams(scn.seed)
    sim, static, road = sensing_setup(scn, rngs)
    for i, sf in enumerate(sense_simulation(scn, sim, static, road, rngs)):  # the one sensing loop
        yield sf.truth, sf.scan, sf.perception, road
        if on_frame is not None:
            on_frame(i + 1, scn.n_frames)


V_COLUMNS = ("frame", "vehicle_id", "range", "view", "visible", "n_points", "detected", "n_dets", "truck")
D_COLUMNS = ("frame", "vehicle_id", "range", "view", "err_box", "err_centroid", "los", "merged", "split", "nees",
             "truck", "n_points")


def characterise(scn: Scenario, on_frame: Callable[[int, int], None] | None = None,
                 merge_sweep: bool = True) -> Characterisation:
    """Measure the perception of ``scn`` against truth (see the module docstring)."""
    lidar = scn.sensor.lidar
    occ = sensors.OcclusionConfig.from_lidar(lidar, pd_nominal=1.0, min_points=scn.sensor.perception.cluster.min_points)
    rows_v: dict[str, list] = {k: [] for k in V_COLUMNS}
    rows_d: dict[str, list] = {k: [] for k in D_COLUMNS}
    clutter, areas = [], []
    rejected: dict[str, int] = {}
    tp = fp = fn = 0
    n = 0
    for truth, scan, perc, road in _frames(scn, on_frame):
        n += 1
        gt, g = scan.source == sensors.GROUND, perc.is_ground
        tp += int(np.count_nonzero(g & gt))
        fp += int(np.count_nonzero(g & ~gt))
        fn += int(np.count_nonzero(~g & gt))
        clutter.append(int(np.count_nonzero(perc.detections.provenance < 0)))
        for reason in np.asarray(perc.rejected.reason, dtype=object):
            rejected[str(reason)] = rejected.get(str(reason), 0) + 1
        areas.append(_road_area_within(road, scan.origin[:2], lidar.max_range_m))
        _vehicle_rows(truth, scan, perc, occ, lidar.max_range_m, rows_v, rows_d)

    res = Characterisation(scn.name, n, lidar.max_range_m, float(np.mean(areas)) if areas else 0.0,
                           tp, fp, fn, rejected=rejected)
    res.vehicles = {k: np.asarray(v) for k, v in rows_v.items()}
    res.vehicles["detected"] = res.vehicles["detected"].astype(bool)
    res.detections = {k: (np.asarray(v).reshape(-1, 2) if k in ("err_box", "err_centroid", "los") else np.asarray(v))
                      for k, v in rows_d.items()}
    res.clutter_per_frame = np.asarray(clutter, dtype=np.float64)
    if merge_sweep:
        res.merge_curve = merge_curve(scn)
    return res


def _vehicle_rows(truth, scan, perc, occ, max_range_m: float, rows_v: dict, rows_d: dict) -> None:
    """Append one frame's rows: one per vehicle within range (ego excluded) to ``rows_v``, one per detection
    of such a vehicle to ``rows_d``."""
    ids, xy, heading, size = truth.ids[1:], truth.xy[1:], truth.heading[1:], truth.size[1:]
    rel = xy - scan.origin[:2]
    rng_ = np.hypot(rel[:, 0], rel[:, 1])
    inr = rng_ <= max_range_m
    if not inr.any():
        return
    ids, xy, heading, size, rel, rng_ = ids[inr], xy[inr], heading[inr], size[inr], rel[inr], rng_[inr]
    los = rel / np.maximum(rng_, 1e-9)[:, None]
    view = np.degrees(np.abs(np.arcsin(np.clip(np.abs(los[:, 0] * np.sin(heading) - los[:, 1] * np.cos(heading)),
                                               0.0, 1.0))))  # 0 end-on, 90 side-on
    visible = np.array([float(occlusion_visibility(scan, xy[k:k + 1], occ, size_m=tuple(size[k]),
                                                 heading=heading[k:k + 1]).visible_fraction[0])
                        for k in range(len(ids))])
    dets = perc.detections
    src_counts = _points_per_source(scan.source)
    n_dets = np.array([int(np.count_nonzero(dets.provenance == i)) for i in ids])
    truck = size[:, 0] > 8.0
    for key, values in (("frame", [truth.frame] * len(ids)), ("vehicle_id", ids), ("range", rng_), ("view", view),
                        ("visible", visible), ("n_points", [src_counts.get(int(i), 0) for i in ids]),
                        ("detected", n_dets > 0), ("n_dets", n_dets), ("truck", truck)):
        rows_v[key] += list(values)

    owners = detection_owners(scan.source, perc.labels, len(dets))
    where = {int(i): k for k, i in enumerate(ids)}
    for j in range(len(dets)):
        k = where.get(int(dets.provenance[j]))
        if k is None:
            continue
        e_box = dets.z[j] - xy[k]
        try:
            nees = float(e_box @ np.linalg.solve(dets.R[j], e_box))
        except np.linalg.LinAlgError:
            nees = float("nan")
        row = dict(frame=truth.frame, vehicle_id=int(ids[k]), range=rng_[k], view=view[k], err_box=e_box,
                   err_centroid=dets.centroid[j] - xy[k], los=los[k], merged=owners[j] >= 2, split=n_dets[k] > 1,
                   nees=nees, truck=bool(truck[k]), n_points=int(dets.n_points[j]))
        for key, value in row.items():
            rows_d[key].append(value)


def _points_per_source(source: np.ndarray) -> dict[int, int]:
    ids, counts = np.unique(source[source >= 0], return_counts=True)
    return dict(zip(ids.tolist(), counts.tolist()))


def detection_owners(source: np.ndarray, labels: np.ndarray, m: int) -> np.ndarray:
    """(m,) number of vehicles holding >= MIN_SHARE (and >= 5) of each detection's points."""
    out = np.zeros(m, np.int64)
    sel = (labels >= 0) & (source >= 0)
    if not sel.any():
        return out
    pairs, counts = np.unique(np.stack([labels[sel], source[sel]]), axis=1, return_counts=True)
    total = np.bincount(labels[labels >= 0], minlength=m)
    big = (counts >= 5) & (counts >= MIN_SHARE * total[pairs[0]])
    np.add.at(out, pairs[0][big], 1)
    return out


def _road_area_within(road: sensors.RoadMap, centre: np.ndarray, radius: float, cell: float = 2.0) -> float:
    """Area [m^2] of the road map (lanes) within ``radius`` of ``centre``, on a ``cell`` grid."""
    g = np.arange(-radius, radius + cell, cell)
    X, Y = np.meshgrid(g, g, indexing="ij")
    pts = np.column_stack([X.ravel(), Y.ravel()])
    pts = pts[np.hypot(pts[:, 0], pts[:, 1]) <= radius] + centre
    return float(np.count_nonzero(road.on_road(pts, 0.0)) * cell * cell)


def merge_curve(scn: Scenario, gaps: tuple[float, ...] = GAPS_M, seed: int = 0) -> dict[float, float]:
    """Merge rate against the bumper-to-bumper gap of two cars (4.6 x 1.8 x 1.5 m) one behind the other, in
    the lane next to the sensor car's (3.5 m across) and two lanes over (7.5 m), seen with the scenario's LiDAR
    and perception from 10 positions each (the front car 8-60 m ahead) and 2 noise draws: the share of the
    views in which both cars show at least the clustering's minimum of points and one detection holds the
    points of both (>= 10 % and >= 5 points each)."""
    lidar, cfg = scn.sensor.lidar, scn.sensor.perception
    rng = np.random.default_rng(seed)
    L, W, H = 4.6, 1.8, 1.5
    road = sensors.RoadMap(np.column_stack([np.arange(-100.0, 201.0), np.full(301, 0.0)]), np.zeros(301),
                           np.full(301, 10.0))
    out = {}
    for gap in gaps:
        merged = views = 0
        for lane_y in (3.5, 7.5):
            for front in np.linspace(8.0, 60.0, 10):
                rear = front - L - gap
                boxes = np.array([[front, lane_y, L, W, H, 0.0, 0.0], [rear, lane_y, L, W, H, 0.0, 0.0]])
                for _ in range(2):
                    s = sensors.scan(lidar, np.zeros(3), boxes, np.array([1, 2]), rng)
                    p = sensors.perceive(s, cfg, road)
                    if not all(np.count_nonzero(s.source == i) >= cfg.cluster.min_points for i in (1, 2)):
                        continue
                    views += 1
                    merged += int(np.any(detection_owners(s.source, p.labels, len(p.detections)) >= 2))
        out[float(gap)] = merged / views if views else float("nan")
    return out


# ---------------------------------------------------------------------- ablation of the static-object methods
ABLATION = {
    "full": {},
    "no map ROI": {"sensor.perception.roi": False},
    "no moving-object test": {"moving_test.enabled": False},
    "neither": {"sensor.perception.roi": False, "moving_test.enabled": False},
    "thesis pipeline": {"sensor.pipeline": "thesis"},
}


def ablation(scenario_data: dict, on_run: Callable[[str], None] | None = None) -> dict[str, dict]:
    """Run the tracker on ``scenario_data`` (a scenario dict) with each static-object method off in turn.
    Returns {variant: scores dict (thesis form and ours)}."""
    from ..pipeline.run import run_scenario
    from ..scenario.spec import apply_overrides, parse_scenario

    out = {}
    for name, over in ABLATION.items():
        if on_run is not None:
            on_run(name)
        data = apply_overrides(scenario_data, over)  # the thesis preset fills only the keys the file leaves unset
        res = run_scenario(parse_scenario(data), record=False)
        out[name] = res.scores.to_dict() | {"hota": res.metrics.get("hota", float("nan"))}
    return out


def measured_settings(ch: Characterisation) -> dict[str, float]:
    """Tracker keys supported by the measurements: P_D of visible vehicles in range (at most 0.99), clutter
    density [1/m^2] over the road within range (at least 1e-7), and sigma_w, the per-axis RMS of the reported
    centre's error (bias included: the tracker's model has none), at least 0.05 m."""
    s = ch.summary()
    sigma = s["centre_rmse_box_m"] / math.sqrt(2.0)
    clutter = s["clutter_per_m2_road"]
    return {"tracker.associator.pd": round(float(np.clip(s["pd_visible"], 0.05, 0.99)), 3),
            "tracker.associator.clutter_density": float(f"{max(clutter, 1e-7):.3g}"),
            "tracker.filter.sigma_w": round(max(sigma, 0.05), 3)}

