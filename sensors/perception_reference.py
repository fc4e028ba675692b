"""Pure-numpy reference versions of the per-object loops that sensors/perception.py (and the scan-line links of
sensors/clustering.py) run compiled.

Each function here is the former numpy code of a perception step, kept as the specification of its compiled
replacement (sensors/perception_jit.py): tests/test_perception_identical.py checks, on ray-cast scans and on
hand-made edge cases, that the compiled path gives the same bits. `union_fits_reference` is also the compiled
merge test's fallback when its decision lies within rounding of a bound, `widest_gaps_reference` the split's when a
key cannot order an object's members.

`cfg` is a sensors.perception.PerceptionConfig (read by attribute; not imported, perception imports this module).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import ConvexHull, QhullError, cKDTree

from roadtrack.sensors.boxfit import min_area_rectangle


def too_big_reference(length, width, top, cfg):
    """Whether footprints of these sides (length >= width) [m] and tops [m] exceed one vehicle's bounds."""
    return (length > cfg.max_length_for(top)) | (width > cfg.max_width_m)


def cut_reference(pts: np.ndarray, obj: np.ndarray, axis: float, cfg) -> tuple[np.ndarray, np.ndarray] | None:
    """The two parts of `obj` (point indices into pts (N, 3) [m]) at its best gap along / across `axis` [rad],
    or None when it should stay whole (module docstring of sensors/perception.py, stage 2)."""
    xy = pts[obj, :2]
    c, s = np.cos(axis), np.sin(axis)
    uv = np.stack([xy @ np.array([c, s]), xy @ np.array([-s, c])], axis=1)  # along, across the axis
    extent = np.ptp(uv, axis=0)
    top = pts[obj, 2].max() - cfg.ground.ground_z_m
    too_big = bool(too_big_reference(extent.max(), extent.min(), top, cfg))
    min_gap = cfg.min_split_gap_m if too_big else cfg.split_gap_m
    best = None
    for dim in (0, 1) if too_big else (0,):  # a vehicle-sized object is cut only along the axis
        order = np.argsort(uv[:, dim], kind="stable")
        t = uv[order, dim]
        o = uv[order, 1 - dim]
        gaps = np.diff(t)
        n = len(t)
        # sides of each part: along this dim from t, across from running min/max of the other coordinate
        left_other = np.maximum.accumulate(o)[:-1] - np.minimum.accumulate(o)[:-1]
        right_other = (np.maximum.accumulate(o[::-1])[::-1] - np.minimum.accumulate(o[::-1])[::-1])[1:]
        left_side = np.maximum(t[:-1] - t[0], left_other)
        right_side = np.maximum(t[-1] - t[1:], right_other)
        i = np.arange(n - 1)
        ok = ((gaps >= min_gap) & (i + 1 >= cfg.cluster.min_points) & (n - i - 1 >= cfg.cluster.min_points)
              & (left_side >= cfg.min_extent_m) & (right_side >= cfg.min_extent_m))
        if ok.any():
            j = int(np.flatnonzero(ok)[np.argmax(gaps[ok])])
            if best is None or gaps[j] > best[0]:
                best = (gaps[j], order[: j + 1], order[j + 1 :])
    if best is None:
        return None
    return obj[np.sort(best[1])], obj[np.sort(best[2])]  # each part keeps obj's canonical order


def split_reference(pts: np.ndarray, obj: np.ndarray, axis: float, cfg) -> list[np.ndarray]:
    """The pieces of one split candidate `obj`: cut_reference again on each part, up to cfg.max_splits deep,
    in the order sensors/perception lists them (the second part of a cut first)."""
    queue = [(obj, 0)]
    pieces = []
    while queue:
        o, depth = queue.pop()
        cut = cut_reference(pts, o, axis, cfg) if depth < cfg.max_splits else None
        if cut is None:
            pieces.append(o)
        else:
            queue += [(cut[0], depth + 1), (cut[1], depth + 1)]
    return pieces


def hull_points_reference(xy: np.ndarray) -> np.ndarray:
    """The convex-hull vertices of xy (n, 2) (all points when they are degenerate): the minimum-area
    rectangle of a union only needs its parts' hulls."""
    if len(xy) < 4:
        return xy
    try:
        return xy[ConvexHull(xy - xy.mean(axis=0)).vertices]
    except QhullError:
        return xy


def union_fits_reference(pts: np.ndarray, group: dict, hull: dict, a: int, b: int, cfg) -> np.ndarray | None:
    """The hull points of groups a and b together (group: root -> point indices) if their union fits one
    vehicle, else None; `hull` caches each group's hull points (a joined group's are its parts' together)."""
    for g in (a, b):
        if g not in hull:
            hull[g] = hull_points_reference(pts[group[g], :2])
    union = np.concatenate([hull[a], hull[b]])
    _, length, width = min_area_rectangle(union)
    top = max(pts[group[a], 2].max(), pts[group[b], 2].max()) - cfg.ground.ground_z_m
    return union if bool(~too_big_reference(length, width, top, cfg)) else None


def unite_reference(pts: np.ndarray, objects: list[np.ndarray], pairs, cfg) -> tuple[np.ndarray, dict]:
    """The merge's union loop: the groups of objects a and b of each pair (a < b), in order, are joined when
    union_fits_reference says their union fits one vehicle. Returns the root (K,) of every object (the smallest
    object of its group) and each root's point indices (its parts in the order they were joined)."""
    parent = list(range(len(objects)))

    def root(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    group = {i: objects[i] for i in range(len(objects))}
    hull: dict[int, np.ndarray] = {}
    for a, b in pairs:
        ra, rb = root(a), root(b)
        if ra == rb:
            continue
        union_hull = union_fits_reference(pts, group, hull, ra, rb, cfg)
        if union_hull is not None:
            keep, drop = min(ra, rb), max(ra, rb)
            parent[drop] = keep
            group[keep] = np.concatenate([group[ra], group[rb]])
            hull[keep] = union_hull
    return np.array([root(i) for i in range(len(objects))], np.int64), group


def point_gap_reference(pts: np.ndarray, a: np.ndarray, b: np.ndarray, gap: float) -> float:
    """The smallest distance [m] between the points a and b (indices into pts (N, 3)) if at most gap, else inf
    (the k-d tree on the larger one)."""
    if len(a) < len(b):
        a, b = b, a
    d, _ = cKDTree(pts[a, :2]).query(pts[b, :2], distance_upper_bound=gap)
    return float(np.min(d)) if np.min(d) <= gap else np.inf


def merge_reference(pts: np.ndarray, objects: list[np.ndarray], flags: list[int], cfg, st,
                    merged_flag: int) -> tuple[list[np.ndarray], list[int], bool]:
    """sensors/perception's point-gap merge (stage 3a): objects whose points come within merge_gap_m, closest
    pairs first, joined while the union fits one vehicle; st the objects' summaries (p_length, thickness, top,
    lo, hi). Returns the objects, their flags (merged_flag on joined ones) and whether any were joined."""
    if len(objects) < 2:
        return objects, flags, False
    length, width = np.maximum(st.p_length, st.thickness), np.minimum(st.p_length, st.thickness)
    idx = np.flatnonzero(~too_big_reference(length, width, st.top, cfg))
    if len(idx) < 2:
        return objects, flags, False
    lo, hi = st.lo[idx], st.hi[idx]
    # axis-aligned box gap of every pair, a lower bound of the points' gap
    gap = np.maximum(np.maximum(lo[None] - hi[:, None], lo[:, None] - hi[None]), 0.0)
    ii, jj = np.nonzero(np.triu(np.hypot(gap[..., 0], gap[..., 1]) <= cfg.merge_gap_m, k=1))
    if len(ii) == 0:
        return objects, flags, False
    pairs = []
    for a, b in zip(idx[ii], idx[jj]):
        d = point_gap_reference(pts, objects[a], objects[b], cfg.merge_gap_m)
        if d <= cfg.merge_gap_m:
            pairs.append((d, min(a, b), max(a, b)))
    roots, group = unite_reference(pts, objects, [(a, b) for _, a, b in sorted(pairs)], cfg)
    size = np.bincount(roots, minlength=len(objects))
    joined = np.zeros(len(objects), np.int64)
    np.bitwise_or.at(joined, roots, np.asarray(flags, np.int64))
    out, out_flags = [], []
    for i in np.flatnonzero(roots == np.arange(len(objects))):
        merged = size[i] > 1
        g = group[i]
        out.append(g[np.lexsort((pts[g, 2], pts[g, 1], pts[g, 0]))] if merged else g)
        out_flags.append(int(joined[i]) | (merged_flag if merged else 0))
    return out, out_flags, len(out) < len(objects)


def open_ends_reference(scan, st, keys: np.ndarray, margin_m: float = 0.5,
                        look: int = 2) -> list[tuple[bool, bool] | None]:
    """Per object of `keys` (st: the objects' summaries, members by starts and n): whether its (first, last)
    azimuth edge, counter-clockwise, is bounded by a nearer return; None for all without a range image.

    sensors/boxfit.open_ends_from_ranges for all objects at once (same rule, same arguments): an object's
    columns start after the widest empty arc of its azimuth columns, and an edge is open when in one of the
    `look` columns beyond it a beam the object uses at that edge returns more than margin_m nearer than the
    object's nearest return in that edge column."""
    if scan.ranges.size == 0 or len(keys) == 0:
        return [None] * len(keys)
    members = np.concatenate([st.members[st.starts[k] : st.starts[k] + st.n[k]] for k in keys])
    ray = scan.ray[members]
    if np.any(ray < 0):
        return [None] * len(keys)
    n_az, n_beams = scan.ranges.shape
    owner = np.repeat(np.arange(len(keys)), st.n[keys])
    az, beam = ray // n_beams, ray % n_beams
    cols = np.unique(owner * n_az + az)  # sorted (object, column) pairs
    c_owner, c_az = cols // n_az, cols % n_az
    start = np.flatnonzero(np.r_[True, c_owner[1:] != c_owner[:-1]])
    end = np.r_[start[1:], len(cols)] - 1
    nxt = np.r_[c_az[1:], 0]
    nxt[end] = c_az[start] + n_az  # the arc from an object's last column round to its first
    gap = nxt - c_az
    widest = np.lexsort((np.arange(len(cols)), -gap, c_owner))[start]  # first widest gap of each object
    first = np.where(widest == end, c_az[start], c_az[np.minimum(widest + 1, len(cols) - 1)])
    last = c_az[widest]
    out = []
    for edge, step in ((first, -1), (last, +1)):
        at_edge = az == edge[owner]
        o, b = owner[at_edge], beam[at_edge]
        here = np.full(len(keys), np.inf)
        np.minimum.at(here, o, scan.ranges[edge[o], b])
        beyond = (edge[o][:, None] + step * np.arange(1, look + 1)[None, :]) % n_az
        nearer = np.any(scan.ranges[beyond, b[:, None]] < (here[o] - margin_m)[:, None], axis=1)
        out.append(np.bincount(o, weights=nearer, minlength=len(keys)) > 0)
    return [(bool(a), bool(b)) for a, b in zip(*out)]


def link_unions_reference(ia, ib, pending, lo, hi, top, holds_cluster, truck_top, truck_len, car_len):
    """The union loop of sensors.perception._linked: the links (L,) joining nodes ia[k] and ib[k] (U nodes with
    bird's-eye boxes lo, hi (U, 2) [m], tops (U,) [m] and whether each holds a cluster (U,) bool), taken in the
    order `pending` (L,), in passes until none joins: a link joins a noise node (or a chain of them) to a union
    holding a cluster while the union's box stays within car_len (truck_len when its top reaches truck_top) [m].
    Returns the root (U,) int64 of every node."""
    parent = list(range(len(lo)))
    lo, hi, top = lo.tolist(), hi.tolist(), top.tolist()
    holds_cluster = holds_cluster.tolist()

    def root(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    pending = pending.tolist()
    grew = True
    while pending and grew:  # passes until no union: a chain of noise points grows from its cluster outwards
        grew, later = False, []
        for k in pending:
            r, s = root(int(ia[k])), root(int(ib[k]))
            if r == s or holds_cluster[r] == holds_cluster[s]:  # one side must hold a cluster, not both
                if r != s and not holds_cluster[r]:
                    later.append(k)  # two noise points: once one of them belongs to a cluster
                continue
            (x0, y0), (x1, y1) = lo[r], lo[s]
            (X0, Y0), (X1, Y1) = hi[r], hi[s]
            box_lo, box_hi, t = (min(x0, x1), min(y0, y1)), (max(X0, X1), max(Y0, Y1)), max(top[r], top[s])
            if max(box_hi[0] - box_lo[0], box_hi[1] - box_lo[1]) > (truck_len if t >= truck_top else car_len):
                continue
            parent[s] = r
            lo[r], hi[r], top[r] = box_lo, box_hi, t
            holds_cluster[r] = True
            grew = True
        pending = later
    return np.array([root(i) for i in range(len(parent))], dtype=np.int64)


def canonical_reference(pts: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """The point indices idx (n,) in lexicographic (x, y, z) order of their points pts (N, 3), equal points in
    idx's order (sensors.perception._canonical)."""
    return idx[np.lexsort((pts[idx, 2], pts[idx, 1], pts[idx, 0]))]


def scan_line_links_reference(points, ray, shape, origin, returned, cfg, labels=None):
    """sensors.clustering.scan_line_links in numpy (the former code of its compiled kernel, perception_jit.line_links):
    pairs (L, 2) int64 of indices into points (N, 3) [m] that are consecutive returns of one beam on one surface."""
    pts = np.asarray(points, np.float64)
    n_az, n_beams = shape
    known = np.flatnonzero(ray >= 0)
    if len(known) < 2 or n_az < 2:
        return np.zeros((0, 2), np.int64)
    at = np.full(n_az * n_beams, -1, np.int64)  # point index of each ray among points
    at[ray[known]] = known
    a, b = np.divmod(ray[known], n_beams)
    nxt = at[((a + 1) % n_az) * n_beams + b]
    gap = (nxt < 0) & ~returned[(a + 1) % n_az, b]  # the next ray returned nothing: look one further
    nxt = np.where(gap, at[((a + 2) % n_az) * n_beams + b], nxt)
    i, j = known[nxt >= 0], nxt[nxt >= 0]
    if labels is not None:
        apart = (labels[i] != labels[j]) | (labels[i] < 0)
        i, j = i[apart], j[apart]
    d = pts[j] - pts[i]
    length = np.linalg.norm(d, axis=1)
    far = np.where(np.linalg.norm(pts[j] - origin, axis=1) >= np.linalg.norm(pts[i] - origin, axis=1), j, i)
    u = pts[far] - origin
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    sin_angle = np.linalg.norm(np.cross(d, u), axis=1) / np.maximum(length, 1e-12)
    ok = (length <= cfg.link_max_gap_m) & (sin_angle >= np.sin(np.deg2rad(cfg.link_min_angle_deg)))
    return np.column_stack([i[ok], j[ok]]).astype(np.int64)


def plurality_reference(source: np.ndarray, n: np.ndarray) -> np.ndarray:
    """sensors.perception._plurality_vehicle in numpy: (K,) per object (its n (K,) consecutive entries of source)
    the most frequent source label if it is a vehicle id (>= 0), else -1; ties go to the smallest label."""
    owner = np.repeat(np.arange(len(n)), n)
    low = int(source.min())
    pairs, count = np.unique(owner * (int(source.max()) - low + 1) + (source - low), return_counts=True)
    p_owner, label = np.divmod(pairs, int(source.max()) - low + 1)
    label = label + low
    best = np.lexsort((label, -count, p_owner))  # by object, most points first, then smallest label
    first = best[np.r_[True, p_owner[best][1:] != p_owner[best][:-1]]]
    return np.where(label[first] >= 0, label[first], -1).astype(np.int64)


def widest_gaps_reference(u: np.ndarray, starts: np.ndarray, n: np.ndarray) -> np.ndarray:
    """(K,) the widest gap between consecutive values of each object's u (sum n,) in sorted order, from one sort
    of all members by the float key object * (ptp(u) + 1) + (u - min(u)) (sensors.perception._split's former
    code; its order among equal keys is numpy's)."""
    owner = np.repeat(np.arange(len(n)), n)
    u_sorted = u[np.argsort(owner * (np.ptp(u) + 1.0) + (u - u.min()))]
    step = np.diff(u_sorted, append=u_sorted[-1])
    step[starts + n - 1] = 0.0  # no gap across two objects
    return np.maximum.reduceat(step, starts)


def numbered_reference(pts: np.ndarray, raw: np.ndarray, min_points: int) -> np.ndarray:
    """sensors/clustering.numbered's former numpy code: labels (N,) for points (N, 3) from raw labels (N,) (-1
    noise), clusters under min_points dropped, the rest numbered 0.. in the lexicographic (x, y, z) order of their
    first points."""
    out = np.full(len(raw), -1, np.int64)
    valid = np.flatnonzero(raw >= 0)
    if len(valid) == 0:
        return out
    lab = raw[valid]
    counts = np.bincount(lab)
    x = pts[valid, 0]
    min_x = np.full(len(counts), np.inf)
    np.minimum.at(min_x, lab, x)
    first = np.flatnonzero((x == min_x[lab]) & (counts[lab] >= min_points))  # candidates for a first point
    order = np.lexsort((pts[valid[first], 2], pts[valid[first], 1], x[first]))
    ids, at = np.unique(lab[first[order]], return_index=True)  # each cluster's first point in that order
    new = np.full(len(counts), -1, np.int64)
    new[ids[np.argsort(at)]] = np.arange(len(ids))
    out[valid] = new[lab]
    return out


def apply_fits_reference(fits: dict, z, heading, extent, R, centre, flags, reason, max_length, cfg) -> None:
    """sensors/perception._apply_fits's former loop, object by object (the same arrays changed in place)."""
    for k, fit in fits.items():
        z[k], heading[k], extent[k, :2], R[k] = fit.centre, fit.heading, (fit.length, fit.width), fit.R
        centre[k] = fit.centre
        flags[k] |= 4 if fit.completed else 0  # sensors.perception.COMPLETED
        seen = (fit.seen_length, fit.seen_width)
        if not cfg.vehicle_like:
            continue
        if cfg.shape_filter and fit.shape != "vehicle":  # by the fitted axis (shape_class uses the principal one)
            reason[k] = fit.shape
        elif max(seen) < cfg.min_extent_m:
            reason[k] = "too_small"
        elif max(seen) > max_length[k]:
            reason[k] = "too_long"
        elif min(seen) > cfg.max_width_m:
            reason[k] = "too_wide"


def grid_labels_reference(pts: np.ndarray, cell_m: float) -> np.ndarray:
    """sensors/clustering._grid's former code: the 8-connected component (N,) (scipy.ndimage.label, numbered 0.. in
    raster order of the cells) of each point's bird's-eye cell of cell_m [m], for points (N, 3) [m]."""
    from scipy import ndimage

    from roadtrack.sensors.grid import bev_cells

    ix, iy, shape = bev_cells(pts, cell_m, "cluster")
    occupied = np.zeros(shape, bool)
    occupied[ix, iy] = True
    cells, _ = ndimage.label(occupied, structure=np.ones((3, 3), bool))
    return cells[ix, iy].astype(np.int64) - 1
