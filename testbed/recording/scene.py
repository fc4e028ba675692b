"""What one frame draws in the 3-D scene: the point cloud, the detections and the tracks, as rerun archetypes.

Each function logs onto an explicit recording stream at the stream's current time (see
testbed/recording/recorder.py for the entity paths). Arrays go to rerun whole (an (N, K, 3) array of line
strips, quaternions for box yaws): per-item Python objects cost more than the logging itself.
"""
from __future__ import annotations

import numpy as np
import rerun as rr

from roadtrack import sensors

from . import palette as pal
from .levels import thinned

GROUND_LABEL = sensors.GROUND
CLUSTER_PALETTE = pal.CLUSTERS
GREEN, RED, GREY = (np.array(c, np.uint8) for c in (pal.DETECTION, pal.CLUTTER, pal.UNLABELLED))
LABELLED_REGIMES = ("track-lost", "ambiguous")
"""The KS regimes (paper 002) a track's label names: the ones that say something is wrong. "unknown" (the test's
window not yet full: every new track for its first seconds) and "tracking" are left out, so labels stay short."""
VELOCITY_S = 0.5
"""The velocity arrows show the distance covered in this many seconds (1 s arrows joined the trails into lines
that looked like lane markings)."""
LAYER_MIN_HALF_M = 0.3
"""SVSF boundary layers are drawn at true size but at least this half width [m], above the car's roof
(:data:`LAYER_Z_M`): a smooth-variable layer of a few centimetres was invisible inside the car. Their values are in
the diagnostics plots (layer tabs); the legend says so. (A fixed magnification does not fit: the layers of one run
span 1 cm to 3 m.)"""
LAYER_Z_M = 2.2  # height [m] the layers are drawn at: above a car's roof and the track's point (1 m)


def track_label(track_id: int, regime: str) -> str:
    """A track's compact label: ``T<id>``, plus the KS regime when it is one of :data:`LABELLED_REGIMES` (e.g.
    "T5 track-lost")."""
    r = str(regime)
    return f"T{int(track_id)} {r}" if r in LABELLED_REGIMES else f"T{int(track_id)}"


def ellipses(centers: np.ndarray, covs: np.ndarray, scale: float, z: float, n: int = 36) -> np.ndarray:
    """Polylines (T, n+1, 3) of the ellipses ``{c + scale * L u : |u| = 1}``, ``covs`` (T, 2, 2)."""
    if len(centers) == 0:
        return np.zeros((0, n + 1, 3))
    t = np.linspace(0.0, 2 * np.pi, n + 1)
    circle = np.stack([np.cos(t), np.sin(t)])  # (2, n+1)
    w, v = np.linalg.eigh(0.5 * (covs + np.swapaxes(covs, -1, -2)))
    axes = v * np.sqrt(np.clip(w, 0.0, None))[:, None, :]  # (T, 2, 2)
    pts = centers[:, :, None] + scale * axes @ circle  # (T, 2, n+1)
    out = np.concatenate([pts, np.full((len(centers), 1, n + 1), z)], axis=1)
    return np.swapaxes(out, 1, 2)


def boxes(centers_xy, size, yaw, z_bottom=None) -> dict:
    """Boxes3D arguments of boxes standing on ``z_bottom`` (default 0): centres (K, 2), sizes (K, 3) [L, W, H],
    yaws (K,) [rad]."""
    size = np.asarray(size, dtype=np.float64).reshape(-1, 3)
    yaw = np.asarray(yaw, dtype=np.float64).reshape(-1)
    zb = np.zeros(len(size)) if z_bottom is None else np.asarray(z_bottom, dtype=np.float64)
    centers = np.column_stack([np.asarray(centers_xy, dtype=np.float64).reshape(-1, 2), zb + size[:, 2] / 2])
    quats = np.column_stack([np.zeros((len(yaw), 2)), np.sin(yaw / 2), np.cos(yaw / 2)])  # xyzw about z
    return dict(centers=centers, half_sizes=size / 2, quaternions=quats)


def log_lidar(rec: rr.RecordingStream, scan, perception, points: str, ground_every: int, truth_copy: bool,
              occlusion: sensors.OcclusionConfig | None) -> None:
    """The point cloud: ``points`` "all" or "thinned" (testbed/recording/levels.py); ``truth_copy`` adds the
    truth-coloured copy and the occlusion shadows (with ``occlusion``)."""
    g = perception.is_ground
    if points == "all":
        ground, objects = np.flatnonzero(g), np.flatnonzero(~g)
    else:
        ground, objects = thinned(g, perception.labels, scan.source, ground_every)
    rec.log("world/lidar/ground", rr.Points3D(scan.points[ground], colors=[pal.GROUND], radii=0.03))
    pts, src, lab = scan.points[objects], scan.source[objects], perception.labels[objects]
    colors = np.where((lab >= 0)[:, None], CLUSTER_PALETTE[lab % len(CLUSTER_PALETTE)], GREY)
    rec.log("world/lidar/objects", rr.Points3D(pts, colors=colors, radii=0.05),
            rr.AnyValues(vehicle_id=src.astype(np.int32), detection=lab.astype(np.int32)))
    _ground_errors(rec, scan, g)
    if truth_copy:
        truth_class = np.where(src >= 0, 1, np.where(src == -1, 2, 0))
        rec.log("world/lidar/truth", rr.Points3D(pts, class_ids=truth_class, radii=0.05))
        if occlusion is not None and len(scan.ranges):
            polys = sensors.shadows(scan, occlusion, is_ground=g)
            rec.log("world/lidar/shadows", rr.LineStrips3D(
                [np.column_stack([np.vstack([p, p[:1]]), np.full(len(p) + 1, 0.05)]) for p in polys],
                colors=[pal.SHADOW], radii=0.015))  # faint: context, not the scene's subject


def _ground_errors(rec: rr.RecordingStream, scan, g: np.ndarray) -> None:
    """Points the ground segmentation got wrong: red an object called road, magenta road called an object."""
    gt = scan.source == GROUND_LABEL
    wrong_obj, wrong_road = np.flatnonzero(g & ~gt), np.flatnonzero(~g & gt)
    colors = np.concatenate([np.tile(pal.OBJECT_AS_ROAD, (len(wrong_obj), 1)),
                             np.tile(pal.ROAD_AS_OBJECT, (len(wrong_road), 1))]).astype(np.uint8).reshape(-1, 3)
    rec.log("world/lidar/ground_errors", rr.Points3D(scan.points[np.concatenate([wrong_obj, wrong_road])],
                                                     colors=colors, radii=0.08))


def log_detections(rec: rr.RecordingStream, detections, perception) -> None:
    """Detections (green from a vehicle, red clutter), fitted boxes coloured by their merge / split /
    completion flags, and the objects the selection rejected, labelled with the test they failed."""
    z, prov, f = detections.z, detections.provenance, detections.flags
    rec.log("world/detections", rr.Points3D(
        np.column_stack([z, np.full(len(z), 0.3)]), radii=0.35, colors=np.where((prov >= 0)[:, None], GREEN, RED),
        labels=[f"v{p}" if p >= 0 else "clutter" for p in prov], show_labels=False))
    color = np.where((prov >= 0)[:, None], GREEN, RED)
    color = np.where((f & sensors.COMPLETED)[:, None] > 0, np.array(pal.COMPLETED, np.uint8), color)
    color = np.where((f & sensors.SPLIT)[:, None] > 0, np.array(pal.SPLIT, np.uint8), color)
    color = np.where((f & sensors.MERGED)[:, None] > 0, np.array(pal.MERGED, np.uint8), color)
    tags = [" ".join(t for bit, t in ((sensors.MERGED, "merged"), (sensors.SPLIT, "split"),
                                      (sensors.COMPLETED, "completed")) if v & bit) or "box" for v in f]
    size = detections.extent.copy()
    size[:, 2] = np.maximum(size[:, 2], 0.1)
    rec.log("world/detections/boxes", rr.Boxes3D(**boxes(z, size, detections.heading), colors=color,
                                                 labels=tags, show_labels=False, radii=0.03))
    rj = perception.rejected if perception is not None else None
    if rj is not None:
        rec.log("world/detections/rejected", rr.Points3D(
            np.column_stack([rj.centre, np.full(len(rj), 0.5)]), radii=0.2, colors=[pal.REJECTED],
            labels=[str(r) for r in rj.reason], show_labels=False))


def log_track_boxes(rec: rr.RecordingStream, ts, colour: np.ndarray) -> None:
    """Box tracking (``tracker.box``): each confirmed track's estimated box (heading, length, width; 1.5 m high)."""
    conf = ts.status == "confirmed"
    b = ts.box[conf]
    rec.log("world/tracks/boxes", rr.Boxes3D(**boxes(ts.xy[conf], np.column_stack([b[:, 1:], np.full(len(b), 1.5)]),
                                                     b[:, 0]), colors=colour[conf], radii=0.04))


def log_sensor_detections(rec: rr.RecordingStream, name: str, xy: np.ndarray) -> None:
    """A further sensor's detections (``name``, e.g. radar) at the positions they imply, xy (M, 2) [m], drawn 2 m up
    (above the cars' boxes, where the top-down view shows them)."""
    rec.log(f"world/sensors/{name}", rr.Points3D(np.column_stack([xy, np.full(len(xy), 2.0)]).reshape(-1, 3),
                                                  radii=0.3, colors=[pal.SENSOR]))


def log_track_points(rec: rr.RecordingStream, ts, colour: np.ndarray) -> None:
    """Track estimates (confirmed labelled compactly, :func:`track_label`; tentative, static) and the confirmed
    tracks' velocity over :data:`VELOCITY_S`; ``colour`` (N, 3) uint8 per track (its slot's, testbed/recording/slots.py)."""
    status, pos, ids, regime = ts.status, ts.xy, ts.ids, ts.regime
    for name, sel, radius in (("confirmed", status == "confirmed", 0.5), ("tentative", status == "tentative", 0.25),
                              ("static", status == "static", 0.35)):
        rec.log(f"world/tracks/{name}", rr.Points3D(
            np.column_stack([pos[sel], np.full(int(sel.sum()), 1.0)]), radii=radius, colors=colour[sel],
            labels=[track_label(i, r) for i, r in zip(ids[sel], regime[sel])], class_ids=ids[sel],
            show_labels=name == "confirmed"))
    conf = status == "confirmed"
    rec.log("world/tracks/velocity", rr.Arrows3D(origins=np.column_stack([pos[conf], np.ones(int(conf.sum()))]),
                                                 vectors=np.column_stack([VELOCITY_S * ts.v[conf],
                                                                          np.zeros(int(conf.sum()))]),
                                                 colors=colour[conf], class_ids=ids[conf]))


def log_track_extras(rec: rr.RecordingStream, ts, layers_before: bool, colour: np.ndarray) -> bool:
    """2-sigma covariance ellipses, the validation gates (in each track's ``colour`` (N, 3)) and the SVSF
    boundary layers (a box of the layer's half widths, at least :data:`LAYER_MIN_HALF_M`, around each updated
    estimate, thesis §2.1, §3.4, above the car; logged once any track has had one, so they clear). Returns whether layers have been logged."""
    info, pos, ids = ts.info, ts.xy, ts.ids
    ppos = ts.cov[:, :2, :2]
    given = np.isfinite(ppos).all(axis=(1, 2))
    rec.log("world/tracks/covariance", rr.LineStrips3D(ellipses(pos[given], ppos[given], 2.0, 1.0),
                                                       colors=colour[given], class_ids=ids[given], radii=0.04))
    where = {int(i): k for k, i in enumerate(ids)}
    gated = info is not None and len(info.ids)
    gate_colour = (np.array([colour[where[int(i)]] if int(i) in where else pal.UNSLOTTED for i in info.ids],
                            dtype=np.uint8).reshape(-1, 3) if gated else np.zeros((0, 3), np.uint8))
    rec.log("world/tracks/gates", rr.LineStrips3D(
        ellipses(info.z_hat, info.S, float(np.sqrt(ts.gate_alpha)), 0.2) if gated else np.zeros((0, 2, 3)),
        colors=gate_colour, class_ids=info.ids if gated else [], radii=0.03))
    rows = [] if info is None else [(k, where[int(i)]) for k, i in enumerate(info.ids)
                                    if int(i) in where and np.isfinite(info.layers[k]).all()]
    if not rows and not layers_before:
        return False
    lk = np.array([r[0] for r in rows], dtype=np.int64)
    tk = np.array([r[1] for r in rows], dtype=np.int64)
    half = np.maximum(info.layers[lk][:, :2], LAYER_MIN_HALF_M) if rows else np.zeros((0, 2))
    rec.log("world/tracks/layers", rr.Boxes3D(
        centers=np.column_stack([pos[tk], np.full(len(tk), LAYER_Z_M)]) if rows else np.zeros((0, 3)),
        half_sizes=np.column_stack([half, np.full(len(tk), 0.05)]), class_ids=ids[tk] if rows else [],
        colors=[pal.LAYER], fill_mode="solid"))  # the only translucent filled boxes of the scene
    return True


TRAIL_EVERY_S = 0.5
"""A trail is a dot per track every this many seconds (a line per frame joined into long lines that looked like
lane markings at motorway speed)."""


class Trails:
    """The confirmed tracks' trails: every :data:`TRAIL_EVERY_S` each confirmed track's position is logged as a
    dot in its colour to ``world/tracks/trajectories``; the blueprint shows that entity over the last
    ``layout.TRAIL_S`` seconds (testbed/recording/layout.py), a trail of breadcrumbs behind each track."""

    def __init__(self, rate_hz: float = 10.0):
        self.every = max(1, int(round(TRAIL_EVERY_S * rate_hz)))
        self.frames = 0

    def log(self, rec: rr.RecordingStream, ts, colour: np.ndarray) -> None:
        k = self.frames
        self.frames += 1
        if k % self.every:
            return
        conf = np.flatnonzero(ts.status == "confirmed")
        rec.log("world/tracks/trajectories", rr.Points3D(
            np.column_stack([ts.xy[conf], np.full(len(conf), 1.0)]), colors=colour[conf].reshape(-1, 3),
            class_ids=ts.ids[conf], radii=0.25))
