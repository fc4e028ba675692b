"""Light sensed frames: what a tracker and the scoring read of a frame, without the point cloud.

A frame as sensed holds about 5 MB on a dense motorway (the LiDAR scan's points, sources and rays, the
perception's per-point labels, and two float64 range images); a light frame keeps the truth, the detections,
the visibility, the road map and the occlusion-aware P_D, whose range image it holds packed (2 mm steps as the
sensing cache keeps them, zlib-compressed: 18 kB on cut_in_out, 25 kB on dense_motorway).
``list(sense(scn, light=True))`` of a long
run then fits in memory, and a tracker fed light frames gives exactly what it gives on full ones
(tests/test_api_streaming.py).
"""
from __future__ import annotations

import zlib
from typing import Callable, Iterable, Iterator

import numpy as np

from roadtrack import sensors

from ..scenario.spec import Scenario
from .cache import quantised, range_dtype
from .frames import PD_RANGE_STEP_M, SensedFrame, occlusion_pd


class PackedRanges:
    """A P_D range image (A, B) [m] (testbed.sensing.pd_scan: inf, or multiples of PD_RANGE_STEP_M) packed as the
    sensing cache quantises it (integer 2 mm steps, :func:`range_dtype`), zlib-compressed: about 18 kB a frame
    against 576 kB as float64 (cut_in_out; the non-ground returns of barriers and cars)."""

    __slots__ = ("shape", "dtype", "blob")

    def __init__(self, ranges: np.ndarray, dtype: np.dtype):
        self.shape, self.dtype = tuple(ranges.shape), np.dtype(dtype)
        self.blob = zlib.compress(quantised(np.asarray(ranges, dtype=np.float64), self.dtype).tobytes(), 1)

    @property
    def nbytes(self) -> int:
        return len(self.blob)

    def dense(self) -> np.ndarray:
        """The range image (A, B) [m], bit-identical to the one it was packed from."""
        steps = np.frombuffer(zlib.decompress(self.blob), dtype=self.dtype).reshape(self.shape)
        return np.where(steps == np.iinfo(self.dtype).max, np.inf,  # as the sensing cache decodes it
                        steps.astype(np.float64) * PD_RANGE_STEP_M)


class LightPD:
    """The occlusion-aware P_D of one light frame, ``pd(xy (T, 2), nominal, trucks=None) -> (T,)`` as
    testbed.sensing.occlusion_pd gives it; the range image is unpacked at each call (about 0.3 ms)."""

    __slots__ = ("pd_for", "ranges", "origin", "pose", "angles")

    def __init__(self, pd_for: Callable, ranges: PackedRanges, origin: np.ndarray, pose: np.ndarray, angles):
        self.pd_for, self.ranges, self.origin, self.pose, self.angles = pd_for, ranges, origin, pose, angles

    def scan(self) -> sensors.Scan:
        """The scan the P_D reads (testbed.sensing.pd_scan): no points, the range image without ground returns."""
        az, el = self.angles
        empty_i = np.zeros(0, dtype=np.int64)
        return sensors.Scan(points=np.zeros((0, 3)), source=empty_i, origin=self.origin, ranges=self.ranges.dense(),
                            ray=empty_i, azimuths=az, elevations=el, pose=self.pose)

    def __call__(self, xy: np.ndarray, nominal: float, trucks: np.ndarray | None = None) -> np.ndarray:
        return self.pd_for(self.scan())(xy, nominal, trucks)


def lighten(frames: Iterable[SensedFrame], scn: Scenario) -> Iterator[SensedFrame]:
    """``frames`` (live or from a sensing cache) as light frames: ``scan`` with no points and no range image,
    ``perception`` and ``pd_scan`` None, ``pd`` a :class:`LightPD` (None when the scenario has it off); truth,
    detections, visibility and road as they were. Beam angles equal to the previous frame's are shared."""
    pd_for, angles = None, None
    dtype = range_dtype(scn.sensor.lidar.max_range_m)
    empty3, empty_i, no_ranges = np.zeros((0, 3)), np.zeros(0, dtype=np.int64), np.zeros((0, 0))
    for sf in frames:
        scan = sf.pd_scan if sf.pd_scan is not None else sf.scan
        if angles is None or not (np.array_equal(angles[0], scan.azimuths)
                                  and np.array_equal(angles[1], scan.elevations)):
            angles = (scan.azimuths, scan.elevations)
        pd = None
        if sf.pd is not None and scn.sensor.occlusion_pd:
            if pd_for is None:
                pd_for = occlusion_pd(scn, sf.road)
            pd = LightPD(pd_for, PackedRanges(scan.ranges, dtype), scan.origin, scan.pose, angles)
        bare = sensors.Scan(points=empty3, source=empty_i, origin=scan.origin, ranges=no_ranges, ray=empty_i,
                            azimuths=angles[0], elevations=angles[1], pose=scan.pose)
        yield SensedFrame(sf.truth, bare, None, sf.detections, sf.visibility, pd, None, sf.road, sf.others)
