"""Record levels: what a run's recording keeps (``record.level`` in a scenario, ``testbed run --record``).

===========  ===========================================================================================
``full``     everything: every LiDAR point (ground and objects, with each point's truth vehicle id and
             detection), the truth-coloured copy (``world/lidar/truth``), the occlusion shadows, the
             ground-segmentation errors, detections, fitted boxes, rejected objects, tracks with their
             covariance, gates and boundary layers, trails, per-track diagnostic series, counts
``default``  as ``full`` with the point cloud thinned: every ``record.ground_decimation``-th ground point
             (16); the non-ground points of each vehicle and each detection's cluster, all of them up
             to :data:`OBJECT_POINTS` and evenly thinned to about that many beyond (a near car has
             1,000-2,000, a far one 6-30: far objects keep every point); every :data:`OTHER_EVERY`-th of
             the other non-ground points (roadside objects, noise); no truth-coloured copy, no shadows
``light``    no point cloud: truth, detections, boxes, rejected objects, tracks with covariance, gates,
             layers and trails, diagnostic series, counts
``tracks``   truth, tracks (estimates, velocities, trails) and the counts only
===========  ===========================================================================================

Every level logs the road, the roadside boxes and the lanes once, as static data. The point cloud is logged
on every ``record.lidar_every``-th frame, and on at most ``record.max_lidar_frames`` frames (:func:`lidar_step`):
the web viewer holds a recording in a memory budget of 2.3 GiB, which the 427 s highway benchmark's default
recording with every frame's point cloud (295 MB) overflowed (it dropped the earliest data, the truth boxes
went missing); with every 4th (116 MB) it held it all.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..scenario.spec import RECORD_LEVELS

OTHER_EVERY = 8  # default level: every 8th non-ground point neither on a vehicle nor in a detection's cluster
OBJECT_POINTS = 256  # default level: points kept per vehicle or detection cluster (about; all of a smaller one)


@dataclass(frozen=True)
class Content:
    """What one level logs each frame."""

    points: str  # "all", "thinned" or "none"
    lidar_truth: bool  # world/lidar/truth and world/lidar/shadows
    detections: bool  # world/detections, its boxes and rejected objects
    track_extras: bool  # covariance ellipses, gates, boundary layers
    diagnostics: bool  # per-track diagnostic series diagnostics/<group>/<name>/<slot>


LEVELS = {
    "full": Content(points="all", lidar_truth=True, detections=True, track_extras=True, diagnostics=True),
    "default": Content(points="thinned", lidar_truth=False, detections=True, track_extras=True, diagnostics=True),
    "light": Content(points="none", lidar_truth=False, detections=True, track_extras=True, diagnostics=True),
    "tracks": Content(points="none", lidar_truth=False, detections=False, track_extras=False, diagnostics=False),
}


def content(level: str) -> Content:
    """The :class:`Content` of ``level``; ValueError naming the levels for another name."""
    try:
        return LEVELS[level]
    except KeyError:
        raise ValueError(f"unknown record level {level!r}; allowed: {', '.join(RECORD_LEVELS)}") from None


def lidar_step(lidar_every: int, max_lidar_frames: int, n_frames: int) -> int:
    """Log the point cloud on every N-th frame (0: never): ``lidar_every``, or more for a run of more than
    ``max_lidar_frames`` frames (0: no limit), so that at most that many frames carry one."""
    if lidar_every == 0 or max_lidar_frames == 0:
        return lidar_every
    return max(lidar_every, math.ceil(n_frames / max_lidar_frames))


def thinned(is_ground: np.ndarray, labels: np.ndarray, source: np.ndarray, ground_every: int,
            other_every: int = OTHER_EVERY, per_object: int = OBJECT_POINTS) -> tuple[np.ndarray, np.ndarray]:
    """Indices of the points the default level keeps, ``(ground (G,), objects (K,))`` into a scan's (N,) arrays
    (``is_ground`` the segmentation's, ``labels`` the detection index or -1, ``source`` the truth vehicle id,
    < 0 for static objects and the road): every ``ground_every``-th ground point; of the non-ground points of
    each detection (``labels >= 0``) or else each vehicle (``source >= 0``), every ``ceil(n / per_object)``-th
    of its n (all when n <= per_object); every ``other_every``-th of the other non-ground points.
    Deterministic (by index), in scan order."""
    ground = np.flatnonzero(is_ground)[::ground_every]
    objects = np.flatnonzero(~is_ground)
    lab, src = labels[objects], source[objects]
    group = np.where(lab >= 0, lab, np.where(src >= 0, -2 - src, np.iinfo(np.int64).min))  # one key per object
    keep = np.zeros(len(objects), dtype=bool)
    other = np.flatnonzero(group == np.iinfo(np.int64).min)
    keep[other[::other_every]] = True
    obj = np.flatnonzero(group != np.iinfo(np.int64).min)
    if len(obj):
        _, inverse, counts = np.unique(group[obj], return_inverse=True, return_counts=True)
        order = np.argsort(inverse, kind="stable")  # each object's points together, in scan order
        start = np.concatenate([[0], np.cumsum(counts)[:-1]])
        rank = np.empty(len(obj), dtype=np.int64)
        rank[order] = np.arange(len(obj)) - start[inverse[order]]
        stride = -(-counts // per_object)  # ceil
        keep[obj[rank % stride[inverse] == 0]] = True
    return ground, objects[keep]
