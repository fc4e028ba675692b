"""Sense once, track many: the sensed frames of a scenario kept on disk, keyed by exactly what changes sensing.

``SensingCache(folder).frames(scn)`` yields the frames of ``scn`` from the cache when an entry for its sensing key
exists, else senses them live and writes the entry once the last frame is done (an interrupted sensing writes
nothing). The key (:func:`sensing_key`) hashes the scenario without the keys that do not change sensing
(``tracker``, ``scoring``, ``record``, ``moving_test``, ``name``, ``description``) together with the source code
of the sensing stages (sensors/, testbed's scenario, world and sensing packages), so changing a
sensing key or that code makes a new entry. A damaged entry is re-sensed with one warning line. Several processes
may share a folder: the first to need an entry senses it while the others wait for it (a lock per key).

An entry is a folder ``<key>/``: ``truth.parquet`` (the truth rows with each vehicle's visibility),
``detections.parquet`` (every field of the detections), ``ranges.parquet`` (per frame the sensor pose and the
range image the occlusion-aware P_D reads, as ``ranges_for_pd`` makes it: 2 mm steps, uint16), ``road.parquet``
(the perception's road map, which that P_D reads too, so a cached run sets up no traffic) and ``meta.json``
(written last: its presence marks the entry complete), and per further sensor (``sensor.extra``) ``others-<name>.parquet``
(its data table, one row per detection: testbed/sensing/sensor.py; data of another form is refused in one line,
never dropped; its visibility and P_D are computed again from the stored data when read). An entry is read frame by frame: its small tables
whole, the range images a batch of frames at a time (:class:`RangeBlobs`). Frames from the cache carry no point cloud and no
perception internals (``scan.points`` is empty, ``perception`` is None): a tracker gets exactly what it gets live
(tests/test_sensing_cache.py checks a tracker run from the cache is identical to one from scratch), a recording
shows no LiDAR points.
"""
from __future__ import annotations

import dataclasses
import hashlib
import inspect
import json
import os
import shutil
import time
import warnings
from pathlib import Path
from typing import Iterator

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from roadtrack import sensors

from ..config import ConfigError, to_dict
from ..common.jsonio import json_text
from ..common.safe_io import make_folder, try_lock, unlock, write_text
from ..scenario.spec import Scenario
from ..world.simulation import TruthFrame
from .frames import PD_RANGE_STEP_M, SensedFrame, occlusion_pd, rng_streams, sense_simulation, sensing_setup
from .cache_others import OtherRows, others_decoder
from .registry import scenario_sensors
from .sensor import SensingContext

CACHE_VERSION = 3
NOT_SENSING = ("tracker", "scoring", "record", "moving_test", "name", "description")
"""Scenario keys that do not change what is sensed."""

WAIT_POLL_S = 0.5
_CODE = ("sensors", "testbed/sensing", "testbed/world", "testbed/scenario")
_fingerprint: str | None = None


class CacheWarning(UserWarning):
    """A damaged sensing-cache entry (re-sensed)."""


def code_fingerprint() -> str:
    """sha256 of the source of the sensing stages (see the module docstring), computed once per process."""
    global _fingerprint
    if _fingerprint is None:
        root = Path(__file__).resolve().parents[2]
        h = hashlib.sha256()
        for rel in _CODE:
            p = root / rel
            files = sorted(p.rglob("*.py")) if p.is_dir() else [p]
            for f in files:
                h.update(str(f.relative_to(root)).encode())
                h.update(f.read_bytes())
        _fingerprint = h.hexdigest()
    return _fingerprint


def sensing_settings(scn: Scenario) -> dict:
    """The scenario as a dict without the keys that do not change sensing (:data:`NOT_SENSING`)."""
    return {k: v for k, v in to_dict(scn).items() if k not in NOT_SENSING}


def sensor_fingerprint(scn: Scenario) -> dict[str, str]:
    """sha256 of the source file of each further sensor's ``sense`` (a plug-in's code is not in
    :func:`code_fingerprint`), by sensor name; empty without ``sensor.extra``."""
    out = {}
    for sensor in scenario_sensors(scn)[1:]:
        try:
            path = inspect.getsourcefile(sensor.sense)
        except TypeError:  # a built-in function: no source file
            path = None
        out[sensor.name] = (hashlib.sha256(Path(path).read_bytes()).hexdigest() if path
                            else f"{getattr(sensor.sense, '__module__', None)}.{getattr(sensor.sense, '__qualname__', None)}")
    return out


def sensing_key(scn: Scenario) -> str:
    """24 hex digits naming what ``scn`` senses (its sensing settings, the sensing code and that of its further
    sensors, the cache version)."""
    text = json.dumps(dict(v=CACHE_VERSION, code=code_fingerprint(), scenario=sensing_settings(scn),
                           sensors=sensor_fingerprint(scn)), sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:24]


def check_cache_folder(folder, key: str = "sensing_cache") -> Path:
    """``folder`` as a Path, or ConfigError (one line naming ``key``) when it is not a path, or it or the nearest
    existing folder above it is a file."""
    if not isinstance(folder, (str, os.PathLike)):
        raise ConfigError(key, f"expected a folder path, got {type(folder).__name__}")
    path = Path(folder)
    if not str(folder):
        raise ConfigError(key, "expected a folder path, got an empty string")
    for p in (path, *path.parents):
        if p.exists() or p.is_symlink():
            if not p.is_dir():
                what = "is a file" if p == path else f"lies in {p}, which is a file"
                raise ConfigError(key, f"{path} {what}, not a folder")
            break
    return path


class SensingCache:
    """Sensed frames on disk under ``folder`` (created if missing; never through a symbolic link)."""

    def __init__(self, folder: str | Path):
        self.folder = check_cache_folder(folder)

    def entry(self, scn: Scenario) -> Path:
        return self.folder / sensing_key(scn)

    def has(self, scn: Scenario) -> bool:
        return (self.entry(scn) / "meta.json").is_file()

    def size_bytes(self, scn: Scenario | None = None) -> int:
        """Bytes on disk of ``scn``'s entry, or of the whole cache."""
        root = self.entry(scn) if scn is not None else self.folder
        return sum(f.stat().st_size for f in root.rglob("*") if f.is_file()) if root.exists() else 0

    def frames(self, scn: Scenario, setup=None, watch=None) -> Iterator[SensedFrame]:
        """The sensed frames of ``scn``: from the entry when it is complete, else sensed and stored. ``setup``: a
        function of no argument giving (sim, static, road) as :func:`sensing_setup` does, called only when the
        frames must be sensed (default: sensing_setup of the scenario); ``watch``: a Stopwatch or None."""
        make_folder(self.folder, "sensing cache")
        entry = self.entry(scn)
        lock_path = self.folder / f".{entry.name}.lock"
        fd = None
        while True:
            if (entry / "meta.json").is_file():
                frames = self._load(scn, entry, watch)
                if frames is not None:
                    if fd is not None:
                        unlock(fd, lock_path)
                    yield from frames
                    return
            if fd is None:
                fd = try_lock(lock_path)
                if fd is None:  # another process is sensing this entry: wait for it
                    time.sleep(WAIT_POLL_S)
                    continue
                continue  # locked: look once more (it may have been finished meanwhile)
            break
        try:
            sim, static, road = setup() if setup is not None else sensing_setup(scn, rng_streams(scn.seed))
            yield from self._sense_and_store(scn, entry, sim, static, road, watch)
        finally:
            unlock(fd, lock_path)

    def _load(self, scn: Scenario, entry: Path, watch) -> Iterator[SensedFrame] | None:
        """The entry's frames (decoded one by one), or None (with one warning line, the entry removed) when it
        cannot be read. The range images are read only when the scenario's occlusion-aware P_D needs them."""
        try:
            meta = json.loads((entry / "meta.json").read_text(encoding="utf-8"))
            if meta.get("version") != CACHE_VERSION or meta.get("key") != entry.name:
                raise ValueError("written by another version")
            tables = {n: pq.read_table(entry / f"{n}.parquet") for n in ("truth", "detections")}
            tables["ranges"] = pq.read_table(entry / "ranges.parquet", columns=["frame", "origin", "pose"])
            blobs = RangeBlobs(entry / "ranges.parquet") if scn.sensor.occlusion_pd else None
            road = _road(pq.read_table(entry / "road.parquet"))
            frames = _decode(scn, meta, tables, road, blobs)  # checks the tables' sizes before the first frame
            extra = scenario_sensors(scn)[1:]
            if extra:
                decode = others_decoder(extra, SensingContext(scn, None, road), {
                    s.name: pq.read_table(entry / f"others-{s.name}.parquet") for s in extra}, meta["others"])
                frames = (dataclasses.replace(sf, others=decode(sf.truth)) for sf in frames)
        except Exception as err:  # noqa: BLE001 - any damage: sense again
            warnings.warn(CacheWarning(f"sensing cache {entry}: damaged ({type(err).__name__}: "
                                       f"{str(err).splitlines()[0] if str(err) else ''}); sensing again"),
                          stacklevel=3)
            shutil.rmtree(entry, ignore_errors=True)
            return None
        if watch is not None:
            watch.lap("simulation")
        return frames

    def _sense_and_store(self, scn, entry: Path, sim, static, road, watch) -> Iterator[SensedFrame]:
        rows = _Rows(range_dtype(scn.sensor.lidar.max_range_m))
        others = OtherRows([s.name for s in scenario_sensors(scn)[1:]])
        rngs = rng_streams(scn.seed)  # the lidar and clutter streams as sensing_setup left them (it draws roadside)
        for sf in sense_simulation(scn, sim, static, road, rngs, watch):
            others.add(sf.index, sf.others)  # refuses (one line) what it cannot store
            rows.add(sf)
            yield sf
        tmp = self.folder / f".{entry.name}.partial-{os.getpid()}"
        shutil.rmtree(tmp, ignore_errors=True)
        make_folder(tmp, "sensing cache entry")
        try:
            for name, table in {**rows.tables(), "road": _road_table(road), **others.tables()}.items():
                pq.write_table(table, tmp / f"{name}.parquet", compression="zstd")
            meta = dict(version=CACHE_VERSION, key=entry.name, frames=rows.n, settings=sensing_settings(scn),
                        azimuths=rows.azimuths, elevations=rows.elevations, shape=rows.shape,
                        range_step_m=PD_RANGE_STEP_M, dtype=rows.dtype.name, others=others.schema)
            write_text(tmp / "meta.json", json_text(meta, default=str))
            shutil.rmtree(entry, ignore_errors=True)
            os.replace(tmp, entry)
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise


def _road_table(road: sensors.RoadMap) -> pa.Table:
    return pa.table(dict(x=road.centre[:, 0], y=road.centre[:, 1], heading=road.heading, half_width=road.half_width))


def _road(table: pa.Table) -> sensors.RoadMap:
    col = {c: table.column(c).to_numpy() for c in table.column_names}
    return sensors.RoadMap(np.column_stack([col["x"], col["y"]]), col["heading"], col["half_width"])


class _Rows:
    """Columns of the sensed frames, appended per frame."""

    def __init__(self, dtype: np.dtype):
        self.n = 0
        self.truth: dict[str, list] = {k: [] for k in ("frame", "time", "vehicle_id", "name", "x", "y", "heading",
                                                         "vx", "vy", "length", "width", "height", "lane", "crashed",
                                                         "n_points", "in_range")}
        self.dets: dict[str, list] = {k: [] for k in ("frame", "z", "provenance", "n_points", "extent", "R",
                                                        "centroid", "heading", "flags")}
        self.ranges: dict[str, list] = {k: [] for k in ("frame", "time", "origin", "pose", "ranges")}
        self.azimuths: list[float] = []
        self.elevations: list[float] = []
        self.shape: list[int] = [0, 0]
        self.dtype = dtype

    def add(self, sf: SensedFrame) -> None:
        t, d, s = sf.truth, sf.detections, sf.pd_scan
        k, m = len(t.ids), len(d.z)
        self.truth["frame"].append(np.full(k, t.frame, np.int64))
        self.truth["time"].append(np.full(k, t.time))
        self.truth["vehicle_id"].append(t.ids)
        self.truth["name"].append(np.array(t.names, dtype=object))
        for col, a in (("x", t.xy[:, 0]), ("y", t.xy[:, 1]), ("heading", t.heading), ("vx", t.velocity[:, 0]),
                       ("vy", t.velocity[:, 1]), ("length", t.size[:, 0]), ("width", t.size[:, 1]),
                       ("height", t.size[:, 2]), ("lane", t.lane), ("crashed", t.crashed),
                       ("n_points", sf.visibility[0]), ("in_range", sf.visibility[1])):
            self.truth[col].append(np.asarray(a))
        self.dets["frame"].append(np.full(m, t.frame, np.int64))
        for col in ("z", "provenance", "n_points", "extent", "R", "centroid", "heading", "flags"):
            self.dets[col].append(np.asarray(getattr(d, col)))
        self.ranges["frame"].append(t.frame)
        self.ranges["time"].append(t.time)
        self.ranges["origin"].append(s.origin.tolist())
        self.ranges["pose"].append(s.pose.tolist())
        self.ranges["ranges"].append(quantised(s.ranges, self.dtype).tobytes())
        if not self.n:
            self.azimuths, self.elevations = s.azimuths.tolist(), s.elevations.tolist()
            self.shape = list(s.ranges.shape)
        self.n += 1

    def tables(self) -> dict[str, pa.Table]:
        truth = {k: np.concatenate(v) if v else np.zeros(0) for k, v in self.truth.items()}
        dets = {}
        for k, v in self.dets.items():
            a = np.concatenate(v) if v else np.zeros(0)
            if a.ndim > 1:  # fixed-size rows, flattened (z (M, 2), R (M, 2, 2), ...)
                width = int(np.prod(a.shape[1:]))
                a = pa.FixedSizeListArray.from_arrays(pa.array(a.reshape(-1)), width)
            dets[k] = a
        ranges = dict(frame=pa.array(self.ranges["frame"], pa.int64()), time=pa.array(self.ranges["time"], pa.float64()),
                      origin=pa.array(self.ranges["origin"], pa.list_(pa.float64(), 3)),
                      pose=pa.array(self.ranges["pose"], pa.list_(pa.float64(), 3)),
                      ranges=pa.array(self.ranges["ranges"], pa.binary()))
        return dict(truth=pa.table({k: pa.array(v) for k, v in truth.items()}), detections=pa.table(dets),
                    ranges=pa.table(ranges))


def range_dtype(max_range_m: float) -> np.dtype:
    """The integer type of a cached range image: uint16 (2 mm steps up to 131 m) or uint32; its largest value
    means no return."""
    return np.dtype(np.uint16 if max_range_m / PD_RANGE_STEP_M < 65534 else np.uint32)


def quantised(ranges: np.ndarray, dtype: np.dtype) -> np.ndarray:
    """A P_D range image (A, B) [m] (testbed.sensing.pd_scan: multiples of PD_RANGE_STEP_M or inf) as integer
    steps of ``dtype`` (:func:`range_dtype`)."""
    finite = np.isfinite(ranges)
    out = np.full(ranges.shape, np.iinfo(dtype).max, dtype)
    out[finite] = np.rint(ranges[finite] / PD_RANGE_STEP_M).astype(dtype)
    return out


def _fixed(col: pa.ChunkedArray, shape: tuple[int, ...], dtype) -> np.ndarray:
    flat = col.combine_chunks()
    values = flat.values.to_numpy(zero_copy_only=False) if len(flat) else np.zeros(0)
    return values.astype(dtype).reshape((len(flat), *shape))


class RangeBlobs:
    """The range images of an entry's ``ranges.parquet`` read :data:`BLOB_BATCH` frames at a time (a long run's
    range images are never all in memory): ``check(n, nbytes)`` reads them once to check their count and sizes,
    iterating gives each image's bytes (a zero-copy buffer) in frame order."""

    def __init__(self, path: Path):
        self.path = path

    def _columns(self) -> Iterator[pa.Array]:
        for batch in pq.ParquetFile(self.path).iter_batches(batch_size=BLOB_BATCH, columns=["ranges"]):
            yield batch.column(0)

    def check(self, n: int, nbytes: int) -> None:
        """ValueError unless there are ``n`` images of ``nbytes`` bytes each."""
        count = 0
        for col in self._columns():
            sizes = pc.binary_length(col).to_numpy(zero_copy_only=False)
            if col.null_count or np.any(sizes != nbytes):
                raise ValueError(f"a range image is not of {nbytes} bytes")
            count += len(col)
        if count != n:
            raise ValueError(f"{count} range images, expected {n}")

    def __iter__(self) -> Iterator:
        for col in self._columns():
            for blob in col:
                yield blob.as_buffer()


BLOB_BATCH = 32
"""Range images read from a cache entry at a time (32 frames of the HDL-32E: 4.6 MB as uint16)."""


def _decode(scn: Scenario, meta: dict, tables: dict, road, blobs: RangeBlobs | None) -> Iterator[SensedFrame]:
    """The frames of an entry's tables, decoded one at a time, the range images read a batch at a time
    (:class:`RangeBlobs`, None when the P_D is off); ValueError before the first frame when the tables do not fit
    ``meta``."""
    n = int(meta["frames"])
    shape = tuple(meta["shape"])
    az, el = np.asarray(meta["azimuths"], np.float64), np.asarray(meta["elevations"], np.float64)
    dtype = np.dtype(meta["dtype"])
    tr = {c: tables["truth"].column(c).to_numpy(zero_copy_only=False) for c in tables["truth"].column_names}
    dt = tables["detections"]
    det = dict(frame=dt.column("frame").to_numpy(), provenance=dt.column("provenance").to_numpy(),
               n_points=dt.column("n_points").to_numpy(), heading=dt.column("heading").to_numpy(),
               flags=dt.column("flags").to_numpy(), z=_fixed(dt.column("z"), (2,), np.float64),
               extent=_fixed(dt.column("extent"), (3,), np.float64), R=_fixed(dt.column("R"), (2, 2), np.float64),
               centroid=_fixed(dt.column("centroid"), (2,), np.float64))
    rg = tables["ranges"]
    origins = _fixed(rg.column("origin"), (3,), np.float64)
    poses = _fixed(rg.column("pose"), (3,), np.float64)
    frames_col = rg.column("frame").to_numpy()
    if len(frames_col) != n or list(frames_col) != list(range(n)):
        raise ValueError(f"{len(frames_col)} frames, expected {n}")
    if blobs is not None:
        blobs.check(n, int(np.prod(shape)) * dtype.itemsize)
    return _frames_of(scn, n, shape, az, el, dtype, tr, det, origins, poses, blobs, road)


def _frames_of(scn, n, shape, az, el, dtype, tr, det, origins, poses, blobs, road) -> Iterator[SensedFrame]:
    t_bounds = np.searchsorted(tr["frame"], np.arange(n + 1))
    d_bounds = np.searchsorted(det["frame"], np.arange(n + 1))
    pd_for = occlusion_pd(scn, road) if scn.sensor.occlusion_pd else None
    empty3, empty_i = np.zeros((0, 3)), np.zeros(0, np.int64)
    no_ranges = np.zeros((0, 0))
    images = iter(blobs) if blobs is not None else None
    for f in range(n):
        a, b = t_bounds[f], t_bounds[f + 1]
        truth = TruthFrame(frame=f, time=float(tr["time"][a]), ids=tr["vehicle_id"][a:b].astype(np.int64),
                           names=tuple(tr["name"][a:b].tolist()),
                           xy=np.column_stack([tr["x"][a:b], tr["y"][a:b]]).astype(np.float64),
                           heading=tr["heading"][a:b].astype(np.float64),
                           velocity=np.column_stack([tr["vx"][a:b], tr["vy"][a:b]]).astype(np.float64),
                           size=np.column_stack([tr["length"][a:b], tr["width"][a:b], tr["height"][a:b]]).astype(np.float64),
                           lane=tr["lane"][a:b].astype(np.int64), crashed=tr["crashed"][a:b].astype(bool))
        vis = (tr["n_points"][a:b].astype(np.int64), tr["in_range"][a:b].astype(bool))
        c, e = d_bounds[f], d_bounds[f + 1]
        dets = sensors.Detections(det["z"][c:e], det["provenance"][c:e], det["n_points"][c:e], det["extent"][c:e],
                                  det["R"][c:e], det["centroid"][c:e], det["heading"][c:e], det["flags"][c:e])
        if images is not None:
            steps = np.frombuffer(next(images), dtype=dtype).reshape(shape)
            ranges = np.where(steps == np.iinfo(dtype).max, np.inf, steps.astype(np.float64) * PD_RANGE_STEP_M)
        else:  # the P_D is off: nothing reads the range image
            ranges = no_ranges
        scan = sensors.Scan(points=empty3, source=empty_i, origin=origins[f], ranges=ranges, ray=empty_i,
                            azimuths=az, elevations=el, pose=poses[f])
        yield SensedFrame(truth, scan, None, dets, vis, pd_for(scan) if pd_for is not None else None, scan, road)
