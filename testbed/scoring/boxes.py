"""Box-overlap scores of box tracking (``tracker.box``): bird's-eye-view IoU and the HOTA / CLEAR / Identity metrics
with IoU as the similarity, as KITTI and AB3DMOT score 3-D MOT with box overlap (here in the ground plane).

A box is [x, y, heading, length, width] (m, rad). ``bev_iou`` intersects the two rotated rectangles exactly
(Sutherland-Hodgman clipping of one convex polygon by the other) for pairs whose centres lie within the sum of
their half diagonals (others are 0). ``box_metrics`` gives TrackEval's HOTA (mean over IoU thresholds 0.05..0.95),
DetA, AssA, LocA, CLEAR's MOTA and MOTP (a match needs IoU >= 0.5) and IDF1 (testbed/scoring/mot_metrics.py, same
definitions with s = IoU), plus the mean IoU of the CLEAR-style nearest pairs.
"""
from __future__ import annotations

import numpy as np

from .mot_metrics import trackeval_scores

BOX_METRIC_KEYS = ("hota", "deta", "assa", "loca", "mota", "motp", "idf1", "id_switches")


def corners(b: np.ndarray) -> np.ndarray:
    """The 4 corners (N, 4, 2) [m] of boxes b (N, 5), counter-clockwise."""
    b = np.asarray(b, dtype=np.float64).reshape(-1, 5)
    c, s = np.cos(b[:, 2]), np.sin(b[:, 2])
    hl, hw = 0.5 * b[:, 3], 0.5 * b[:, 4]
    local = np.array([[1, -1], [1, 1], [-1, 1], [-1, -1]], dtype=np.float64)  # (4, 2) in (length, width) units
    dx = local[None, :, 0] * hl[:, None]
    dy = local[None, :, 1] * hw[:, None]
    return np.stack([b[:, None, 0] + c[:, None] * dx - s[:, None] * dy,
                     b[:, None, 1] + s[:, None] * dx + c[:, None] * dy], axis=-1)


def _area(p: np.ndarray) -> float:
    """Area of a polygon (K, 2) by the shoelace formula (0 for fewer than 3 vertices)."""
    if len(p) < 3:
        return 0.0
    x, y = p[:, 0], p[:, 1]
    return 0.5 * abs(float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))


def _clip(subject: np.ndarray, clipper: np.ndarray) -> np.ndarray:
    """The part of convex polygon ``subject`` inside convex counter-clockwise polygon ``clipper`` (Sutherland-Hodgman)."""
    out = subject
    for a, b in zip(clipper, np.roll(clipper, -1, axis=0)):
        if len(out) == 0:
            break
        edge = b - a
        side = edge[0] * (out[:, 1] - a[1]) - edge[1] * (out[:, 0] - a[0])  # > 0: left of the edge, inside
        pts = []
        for i in range(len(out)):
            j = (i + 1) % len(out)
            if side[i] >= 0:
                pts.append(out[i])
            if (side[i] >= 0) != (side[j] >= 0):
                t = side[i] / (side[i] - side[j])
                pts.append(out[i] + t * (out[j] - out[i]))
        out = np.array(pts).reshape(-1, 2)
    return out


def bev_iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """IoU (N, M) in [0, 1] of boxes a (N, 5) and b (M, 5) [x, y, heading, length, width] in the ground plane."""
    a, b = np.asarray(a, dtype=np.float64).reshape(-1, 5), np.asarray(b, dtype=np.float64).reshape(-1, 5)
    out = np.zeros((len(a), len(b)))
    if not len(a) or not len(b):
        return out
    ca, cb = corners(a), corners(b)
    reach = 0.5 * (np.hypot(a[:, 3], a[:, 4])[:, None] + np.hypot(b[:, 3], b[:, 4])[None, :])
    near = np.hypot(a[:, None, 0] - b[None, :, 0], a[:, None, 1] - b[None, :, 1]) < reach
    area_a, area_b = a[:, 3] * a[:, 4], b[:, 3] * b[:, 4]
    for i, j in zip(*np.nonzero(near)):
        inter = _area(_clip(ca[i], cb[j]))
        union = area_a[i] + area_b[j] - inter
        out[i, j] = inter / union if union > 0 else 0.0
    return out


def box_metrics(truth: dict[str, np.ndarray], tracks: dict[str, np.ndarray], n_frames: int) -> dict[str, float]:
    """Box-overlap HOTA / CLEAR / Identity (module docstring) of truth ``frame (N,)``, ``vehicle_id (N,)``,
    ``box (N, 5)`` and confirmed tracks ``frame (Q,)``, ``track_id (Q,)``, ``box (Q, 5)``; keys BOX_METRIC_KEYS and
    ``mean_iou`` (of each truth row with a track overlapping it, its largest IoU)."""
    g_frame = np.asarray(truth["frame"], dtype=np.int64).reshape(-1)
    t_frame = np.asarray(tracks["frame"], dtype=np.int64).reshape(-1)
    g_box = np.asarray(truth["box"], dtype=np.float64).reshape(-1, 5)
    t_box = np.asarray(tracks["box"], dtype=np.float64).reshape(-1, 5)
    best: list[np.ndarray] = []

    def similarity(f: int, gi: np.ndarray, ti: np.ndarray) -> np.ndarray:
        iou = bev_iou(g_box[gi], t_box[ti])
        if iou.size:
            best.append(iou.max(axis=1)[iou.max(axis=1) > 0])
        return iou

    out = trackeval_scores(g_frame, np.asarray(truth["vehicle_id"], dtype=np.int64).reshape(-1), t_frame,
                           np.asarray(tracks["track_id"], dtype=np.int64).reshape(-1), int(n_frames), similarity)
    got = np.concatenate(best) if best else np.zeros(0)
    out["mean_iou"] = float(got.mean()) if got.size else 0.0
    return out
