"""Static roadside objects (guard rails, posts, sign panels, trees) placed along the road edges.

They are real geometry for the ray caster: whatever of them survives ground removal, clustering and the
vehicle-like test becomes clutter, as in a real perception stack. Placement is seeded.

Where another road edge faces an edge (a motorway's median, the inside of the U-turn), an object is only
placed if it stays in the edge's own half of the gap: a 4 m median gets its two guard rails and nothing
else. The random draws are the same either way, so roads without such a gap keep their objects.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from ..scenario.spec import RoadsideSpec

# (length, width, height) [m]
BARRIER_SEGMENT = (4.0, 0.3, 0.75)  # guard rail
POST = (0.2, 0.2, 1.2)
SIGN = (2.0, 0.15, 1.2)  # panel, lifted by SIGN_LIFT
SIGN_LIFT = 1.0
TRUNK = (0.4, 0.4)  # trunk footprint [m]; its height is the crown's lift
CROWN_SIZE_RANGE = ((2.5, 5.0), (2.5, 5.0), (2.0, 5.0))
CROWN_LIFT_RANGE = (2.2, 3.5)
BUSH_SIZE_RANGE = ((1.0, 3.5), (1.0, 3.5), (0.8, 2.5))


def _along(points: np.ndarray, spacing: float, phase: float = 0.0) -> np.ndarray:
    """Indices of edge samples (1 m apart) every ``spacing`` metres."""
    if spacing <= 0:
        return np.zeros(0, dtype=np.int64)
    return np.arange(int(phase) % max(int(spacing), 1), len(points), max(int(round(spacing)), 1))


def edge_room(edges: list[tuple[np.ndarray, np.ndarray]]) -> list[np.ndarray]:
    """Free width (P,) [m] in front of every edge point along its outward normal, up to the nearest other
    road edge that faces it (``inf`` where none does): a median's width between two carriageways.

    A point of another edge faces point p when it lies more than 0.5 m in front of p and within 1 m of
    p's normal line (edges are sampled every 1 m; the nearest point of each other edge is tested).
    """
    trees = [cKDTree(pts) if len(pts) else None for pts, _ in edges]
    out = []
    for i, (pts, normals) in enumerate(edges):
        room = np.full(len(pts), np.inf)
        for j, tree in enumerate(trees):
            if j == i or tree is None or len(pts) == 0:
                continue
            _, k = tree.query(pts)
            d = edges[j][0][k] - pts
            ahead = np.einsum("ij,ij->i", d, normals)
            side = np.abs(d[:, 0] * normals[:, 1] - d[:, 1] * normals[:, 0])
            room = np.where((ahead > 0.5) & (side < 1.0), np.minimum(room, ahead), room)
        out.append(room)
    return out


def roadside_boxes(edges: list[tuple[np.ndarray, np.ndarray]], spec: RoadsideSpec,
                   rng: np.random.Generator) -> np.ndarray:
    """Boxes ``(K, 7)`` [cx, cy, L, W, H, yaw, z_bottom] beside the road.

    ``edges``: list of (points (P, 2), outward normals (P, 2)) sampled every 1 m (see
    :func:`testbed.world.simulation.road_edges`). An object whose far side would pass the middle of the gap to a
    facing edge (:func:`edge_room`) is left out; guard rails move in to fit (a median narrower than
    2 x ``barrier_offset_m`` + 0.3 m).
    """
    out: list[list[float]] = []
    for (pts, normals), room in zip(edges, edge_room(edges)):
        if len(pts) < 2:
            continue
        half = room / 2.0  # (P,) [m]
        tangent = np.gradient(pts, axis=0)
        yaw = np.arctan2(tangent[:, 1], tangent[:, 0])
        off = spec.barrier_offset_m
        if spec.barriers:
            seg = int(BARRIER_SEGMENT[0])
            for i in range(seg // 2, len(pts), seg):
                c = pts[i] + normals[i] * min(off, half[i] - BARRIER_SEGMENT[1] / 2)
                out.append([c[0], c[1], *BARRIER_SEGMENT, yaw[i], 0.0])
        for i in _along(pts, spec.post_spacing_m, phase=rng.integers(0, 1000)):
            if off + 0.5 + POST[1] / 2 <= half[i]:
                c = pts[i] + normals[i] * (off + 0.5)
                out.append([c[0], c[1], *POST, yaw[i], 0.0])
        length_km = len(pts) / 1000.0
        for _ in range(rng.poisson(spec.signs_per_km * length_km)):
            i = rng.integers(0, len(pts))
            c = pts[i] + normals[i] * (off + 1.5)
            yaw_s = yaw[i] + rng.uniform(-0.3, 0.3)
            if off + 1.5 + SIGN[0] / 2 <= half[i]:
                out.append([c[0], c[1], *SIGN, yaw_s, SIGN_LIFT])
        _trees(out, rng, pts, normals, half, off, spec.trees_per_km * length_km)
        for _ in range(rng.poisson(spec.bushes_per_km * length_km)):
            i = rng.integers(0, len(pts))
            size = [rng.uniform(lo, hi) for lo, hi in BUSH_SIZE_RANGE]
            dist = off + 1.0 + size[1] / 2 + rng.uniform(0.0, 6.0)
            c = pts[i] + normals[i] * dist
            yaw_b = rng.uniform(-np.pi, np.pi)
            if dist + np.hypot(size[0], size[1]) / 2 <= half[i]:
                out.append([c[0], c[1], *size, yaw_b, 0.0])
    return np.asarray(out, dtype=np.float64).reshape(-1, 7)


def _trees(out: list, rng: np.random.Generator, pts: np.ndarray, normals: np.ndarray, half: np.ndarray,
           off: float, expected: float) -> None:
    """Append Poisson(``expected``) trees (trunk + crown boxes) along one edge to ``out``."""
    for _ in range(rng.poisson(expected)):
        i = rng.integers(0, len(pts))
        crown = [rng.uniform(lo, hi) for lo, hi in CROWN_SIZE_RANGE]
        lift = rng.uniform(*CROWN_LIFT_RANGE)
        dist = off + 2.0 + crown[1] / 2 + rng.uniform(0.0, 8.0)
        c = pts[i] + normals[i] * dist
        yaw_t = rng.uniform(-np.pi, np.pi)
        if dist + np.hypot(crown[0], crown[1]) / 2 <= half[i]:
            out.append([c[0], c[1], *TRUNK, lift, yaw_t, 0.0])
            out.append([c[0], c[1], *crown, yaw_t, lift])


def clear_of_lanes(boxes: np.ndarray, centre: np.ndarray, heading: np.ndarray, half_width: np.ndarray) -> np.ndarray:
    """Boolean mask (K,) of the boxes ``(K, 7)`` whose footprint stays off every lane.

    The lanes are given as centre-line samples (at most ~1 m apart): ``centre (P, 2)`` [m], ``heading (P,)``
    [rad], ``half_width (P,)`` [m]. A box is on a lane when its centre is closer to the nearest sample than
    that lane's half width plus the box's own half extent across the lane there (so a guard rail along a
    lane edge stays, a sign turned across it does not). Roads made by highway-env environments (shared
    borders of opposite lanes, roundabouts, ramps) otherwise get roadside objects on their lanes.
    """
    if len(boxes) == 0 or len(centre) == 0:
        return np.ones(len(boxes), dtype=bool)
    dist, k = cKDTree(centre).query(boxes[:, :2])
    rel = boxes[:, 5] - heading[k]
    across = np.abs(boxes[:, 3] / 2 * np.cos(rel)) + np.abs(boxes[:, 2] / 2 * np.sin(rel))
    return dist > half_width[k] + across


def boxes_near(boxes: np.ndarray, center_xy: np.ndarray, radius: float) -> np.ndarray:
    """Boolean mask (K,) of boxes whose centre lies within ``radius`` (+ their half diagonal) of a point."""
    if len(boxes) == 0:
        return np.zeros(0, dtype=bool)
    d = np.hypot(boxes[:, 0] - center_xy[0], boxes[:, 1] - center_xy[1])
    return d <= radius + 0.5 * np.hypot(boxes[:, 2], boxes[:, 3])
