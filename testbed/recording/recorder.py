"""rerun recording of a run: one ``.rrd`` with a default blueprint (testbed/recording/layout.py) and stable
entity paths; what is kept depends on the record level (testbed/recording/levels.py: full, default, light,
tracks).

Entity paths (all in the world frame, z up, metres):

=================================  ==========================================================
``world/road/lanes``               lane borders (static LineStrips3D)
``world/roadside``                 roadside objects (static Boxes3D)
``world/truth/vehicles``           true vehicle boxes, labelled with their ids (Boxes3D)
``world/truth/ego``                the sensor car (Boxes3D)
``world/ego``                      the sensor car's pose (Transform3D): the frame of the views, which follow it
``world/lidar/ground``             ground points (Points3D, grey)
``world/lidar/objects``            non-ground points, coloured by detection (grey: noise or rejected); hover shows
                                   each point's truth ``vehicle_id`` (-1 static object, -2 road) and ``detection``
``world/lidar/truth``              the same points coloured by truth: vehicle, static object, road (class ids;
                                   full level only, hidden in the default blueprint)
``world/lidar/ground_errors``      points the ground segmentation got wrong (red: object called road; magenta:
                                   road called object)
``world/lidar/shadows``            regions hidden behind nearer objects, from the range image (LineStrips3D;
                                   full level only)
``world/detections``               detections: green from a vehicle, red clutter (Points3D)
``world/detections/boxes``         fitted vehicle boxes: magenta merged fragments, cyan split from a larger
                                   cluster, yellow completed beyond the points (one face seen) (Boxes3D)
``world/detections/rejected``      objects the selection removed, labelled with the test they failed (Points3D)
``world/tracks/confirmed``         confirmed track estimates, labelled T<id> (Points3D)
``world/tracks/tentative``         tentative track estimates (Points3D)
``world/tracks/static``            confirmed tracks not seen to move (moving-object test), not reported (Points3D)
``world/tracks/velocity``          confirmed track velocity over 0.5 s (Arrows3D)
``world/tracks/covariance``        2-sigma position covariance ellipses (LineStrips3D)
``world/tracks/gates``             validation gates of the predicted tracks (LineStrips3D)
``world/tracks/layers``            SVSF boundary layers around the updated estimates, at least 0.6 m (Boxes3D)
``world/tracks/trajectories``      trails: a dot per confirmed track every 0.5 s (Points3D); the blueprint shows the
                                   last 5 s of them
``diagnostics/<group>/<name>/<k>`` per-track diagnostic series of confirmed tracks, grouped by quantity (score,
                                   NIS, gate volume, layers, mode probabilities, ...; testbed/recording/diagnostics.py):
                                   one series per slot k (testbed/recording/slots.py), a NaN (a gap) when the slot's
                                   track stops being confirmed; Scalars, sent in columns every
                                   :data:`SERIES_FLUSH_FRAMES` frames
``diagnostics/slots/track_id/<k>`` the track id holding slot k
``legend``                         the colour key (static EncodedImage, PNG; testbed/recording/legend.py)
``world/events``                   rings around the cars of the run's events (relabel, false track, missed car),
                                   labelled with their number and cause, for 3 s (testbed/recording/events.py)
``events``                         the events as a text log, one line each at its time (TextLog)
``metrics/<name>``                 per-frame counts: tracks, detections, clutter, points; and the measured
                                   perception statistics: ground precision / recall, P_D of the vehicles in
                                   range, merged / split detections, rejected objects (Scalars)
=================================  ==========================================================

Timelines: ``frame`` (sequence) and ``sim_time`` (duration, seconds).
"""
from __future__ import annotations

import os
import threading
import time
import warnings
from pathlib import Path

import numpy as np

# Long runs are written without rerun's footer (FOOTER_MAX_FRAMES) and compacted when they close, which adds
# it: rerun's warning about the missing footer is off unless RUST_LOG is set (set before rerun starts logging).
os.environ.setdefault("RUST_LOG", "warn,re_log_encoding::rrd::file_sink=error")
import rerun as rr  # noqa: E402

from roadtrack import sensors

from ..common.safe_io import refuse_link
from . import palette as pal
from .diagnostics import SLOT_IDS, series_label, series_path
from .layout import blueprint
from .legend import legend_png
from .levels import content
from .events import log_events
from . import rrd
from .slots import Slots, colours
from .scene import (GROUND_LABEL, Trails, boxes, log_detections, log_lidar, log_sensor_detections, log_track_boxes,
                    log_track_extras,
                    log_track_points)

APP_ID = "roadtrack"
METRICS = ("tracks_confirmed", "tracks_tentative", "tracks_static", "detections", "clutter_detections",
           "lidar_points", "ground_precision", "ground_recall", "pd_in_range", "merged_detections",
           "split_detections", "rejected_objects")
METRIC_COLOURS = {"detections": pal.DETECTION, "clutter_detections": pal.CLUTTER,
                  "tracks_confirmed": tuple(int(v) for v in pal.SLOTS[0]), "tracks_tentative": pal.UNSLOTTED,
                  "tracks_static": pal.REJECTED}
"""The count plots' lines in the scene's colours (rerun's own picks gave detections and clutter two near-identical
greens; clutter is red in the scene)."""
TRUTH_CLASSES = ((0, "road", (90, 90, 90)), (1, "vehicle", (40, 200, 90)), (2, "static object", (160, 110, 60)))
CLOSE_STALL_S = 30.0
"""Seconds :meth:`Recorder.close` waits for rerun to flush and release the file while the file does not grow.
rerun 0.41 can block forever in ``flush()`` and ``disconnect()`` once its file writer died on a full disk (an
upstream race, seen in CI): the recording is then given up on, so a run ends with its one line within this
bound. A slow disk that is still being written is waited for."""
CLOSE_POLL_S = 0.5  # how often close() looks at the file's size
BATCHING = rr.ChunkBatcherConfig(flush_tick=5.0, flush_num_bytes=16 << 20)
"""rerun's chunk batcher: up to 5 s or 16 MiB per chunk (its default 0.2 s / 2 MiB cut a slow run's frames into
chunks of one to three rows: 52,000 chunks for the 427 s highway benchmark); the file is compacted when the
recording closes (testbed/recording/rrd.py)."""
SERIES_FLUSH_FRAMES = 30
"""The metrics and per-track diagnostic series are buffered and sent in columns every N frames (3 s at 10 Hz:
a viewer following a live run sees them within seconds)."""
FOOTER_MAX_FRAMES = 1200
"""Recordings of up to this many frames end with an rrd footer (a manifest of every chunk, for random access).
rerun keeps that manifest in memory until the file is closed: ~17 kB per frame here (about 3.5 chunks a
frame), 200 MB for a 20-minute run. Longer runs are written without it, as rerun advises for long streams;
the compaction when the recording closes (testbed/recording/rrd.py) adds one."""


class Recorder:
    """Writes one run to ``path`` (``.rrd``). Call :meth:`static` once, :meth:`frame` per frame, :meth:`close`.
    ``level``: what it keeps (testbed/recording/levels.py); ``rate_hz``: the frame rate (for the trails'
    time range in the blueprint); ``compact``: :meth:`close` starts the file's compaction, then call
    :meth:`wait_compacted` (or :meth:`cancel_compaction`)."""

    def __init__(self, path: str | Path, recording_id: str, lidar_every: int = 1, ground_decimation: int = 16,
                 write_footer: bool = True, occlusion: sensors.OcclusionConfig | None = None,
                 max_range_m: float = 70.0, level: str = "default", rate_hz: float = 10.0, compact: bool = False):
        self.content = content(level)  # an unknown level fails before any file is made
        self.rate_hz = rate_hz
        self.path = Path(path)
        self.occlusion = occlusion  # draw the occluders' shadows with it (None: no shadows)
        self.max_range_m = max_range_m
        self.lidar_every = lidar_every
        self.ground_decimation = ground_decimation
        self.compact = compact  # merge the file's chunks when it closes (testbed/recording/rrd.py)
        self.compaction: rrd.Compaction | None = None
        refuse_link(self.path)  # rerun opens it following links: a planted one is refused, never written through
        self.rec = rr.RecordingStream(APP_ID, recording_id=recording_id, batcher_config=BATCHING)
        self.rec.set_log_time_enabled(False)  # wall-clock log times: meaningless in a replay, an index per chunk
        self.rec.save(str(self.path), write_footer=write_footer)  # see FOOTER_MAX_FRAMES
        self.rec.send_blueprint(blueprint(rate_hz), make_active=True, make_default=True)
        self.rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        self.rec.log("world/lidar", rr.AnnotationContext(
            [rr.AnnotationInfo(id=i, label=name, color=c) for i, name, c in TRUTH_CLASSES]), static=True)
        for name in METRICS:
            style = dict(colors=[METRIC_COLOURS[name]]) if name in METRIC_COLOURS else {}
            self.rec.log(f"metrics/{name}", rr.SeriesLines(names=name.replace("_", " "), **style), static=True)
        self.rec.log("legend", rr.EncodedImage(contents=legend_png(), media_type="image/png"), static=True)
        self.legend_extras: tuple[str, ...] = ()  # legend rows added by what the run draws (legend.EXTRAS)
        self.trails = Trails(rate_hz)
        self.slots = Slots()
        self.series: dict[tuple[str, int], tuple[list[int], list[float], list[float]]] = {}
        self.metrics: dict[str, tuple[list[int], list[float], list[float]]] = {}
        self.series_frames = 0
        self.named: set[str] = set()  # series whose legend name and colour are logged
        self.drawing: set[tuple[str, int]] = set()  # (series path, slot) with a value in the last frame
        self.layers_logged = False

    def static(self, lanes: list[np.ndarray], roadside: np.ndarray) -> None:
        """Road lane borders (list of (P, 2)) and roadside boxes (K, 7) [cx, cy, L, W, H, yaw, z_bottom], logged
        once as static data (shown at every time)."""
        strips = [np.column_stack([ln, np.zeros(len(ln))]) for ln in lanes]
        self.rec.log("world/road/lanes", rr.LineStrips3D(strips, colors=[pal.ROAD], radii=0.05), static=True)
        if len(roadside):
            self.rec.log("world/roadside", rr.Boxes3D(**boxes(roadside[:, :2], roadside[:, 2:5], roadside[:, 5],
                                                              roadside[:, 6]), colors=[pal.ROADSIDE]), static=True)

    def _legend(self, extras: tuple[str, ...]) -> None:
        """Re-log the legend (static) with the rows of ``extras`` once the run first draws them."""
        if set(extras) <= set(self.legend_extras):
            return
        self.legend_extras = tuple(sorted(set(extras) | set(self.legend_extras)))
        self.rec.log("legend", rr.EncodedImage(contents=legend_png(self.legend_extras), media_type="image/png"),
                     static=True)

    def frame(self, truth, scan, perception, detections, ts, others: dict[str, np.ndarray] | None = None) -> None:
        """Log one frame. ``ts``: the tracker's testbed.tracking.TrackSet after the step, its status "confirmed",
        "tentative" or "static" (the moving-object test's); its ``info`` (the built-in trackers' StepInfo) adds
        the gates and boundary layers. ``scan`` and ``perception`` may be None (no point cloud is logged).
        ``others``: the further sensors' detections by name, as the positions they imply (M, 2) [m]."""
        rec, want = self.rec, self.content
        rec.set_time("frame", sequence=int(truth.frame))
        rec.set_time("sim_time", duration=float(truth.time))
        self._truth(truth)
        if want.points != "none" and self.lidar_every and truth.frame % self.lidar_every == 0 and scan is not None:
            log_lidar(rec, scan, perception, want.points, self.ground_decimation, want.lidar_truth, self.occlusion)
        if want.detections:
            log_detections(rec, detections, perception)
            for name, xy in (others or {}).items():
                log_sensor_detections(rec, name, xy)
        self._legend(("sensors",) * bool(others and want.detections) + ("boxes",) * (ts.box is not None))
        status = ts.status
        slot = self.slots.update(ts.ids, status == "confirmed")
        colour = colours(slot)
        log_track_points(rec, ts, colour)
        if ts.box is not None:
            log_track_boxes(rec, ts, colour)
        if want.track_extras:
            self.layers_logged = log_track_extras(rec, ts, self.layers_logged, colour)
        self.trails.log(rec, ts, colour)
        if want.diagnostics:
            self._diagnostics(truth, ts, slot)
        counts = dict(tracks_confirmed=int(np.count_nonzero(status == "confirmed")),
                      tracks_tentative=int(np.count_nonzero(status == "tentative")),
                      tracks_static=int(np.count_nonzero(status == "static")), detections=len(detections.z),
                      clutter_detections=int(np.count_nonzero(detections.provenance < 0)),
                      lidar_points=0 if scan is None else len(scan.points))
        if scan is not None:
            counts.update(perception_stats(truth, scan, perception, detections, self.max_range_m))
        self._metrics(truth, counts)
        self.series_frames += 1
        if self.series_frames >= SERIES_FLUSH_FRAMES:
            self._flush_series()

    def events(self, events, truth, tracks) -> None:
        """Mark the run's ``events`` (testbed.scoring.events.run_events; ``truth``, ``tracks``: its tables as
        DataFrames) in the recording: the ``events`` text log and rings on ``world/events``
        (testbed/recording/events.py). Call after the last frame, before :meth:`close`."""
        log_events(self.rec, events, truth, tracks, self.rate_hz)

    def _truth(self, truth) -> None:
        """The sensor car's pose (world/ego: the views' frame), its box and the other vehicles' boxes."""
        labels = [f"{n} ({i})" for n, i in zip(truth.names, truth.ids)]
        half = float(truth.heading[0]) / 2
        self.rec.log("world/ego", rr.Transform3D(translation=[truth.xy[0, 0], truth.xy[0, 1], 0.0],
                                                 quaternion=[0.0, 0.0, np.sin(half), np.cos(half)]))
        self.rec.log("world/truth/ego", rr.Boxes3D(**boxes(truth.xy[:1], truth.size[:1], truth.heading[:1]),
                                                   labels=["sensor car"], show_labels=False,  # the legend's solid box
                                                   colors=[pal.EGO], fill_mode="solid"))
        self.rec.log("world/truth/vehicles", rr.Boxes3D(**boxes(truth.xy[1:], truth.size[1:], truth.heading[1:]),
                                                        labels=labels[1:], class_ids=truth.ids[1:],
                                                        show_labels=False))

    def _metrics(self, truth, values: dict[str, float]) -> None:
        """Buffer the frame's counts and statistics (``metrics/<name>``); sent in columns with the series."""
        for name, value in values.items():
            f, tm, vs = self.metrics.setdefault(name, ([], [], []))
            f.append(int(truth.frame)); tm.append(float(truth.time)); vs.append(float(value))

    def _diagnostics(self, truth, ts, slot: np.ndarray) -> None:
        """Buffer each slot's confirmed track's diagnostics (``slot`` (N,) the slot of each of ``ts.ids``) as
        series ``diagnostics/<group>/<name>/<slot>``, and the slots' track ids; a slot whose track stopped
        being confirmed (or was deleted) gets one NaN, a gap in its line."""
        now: dict[tuple[str, int], float] = {}
        for k, tid in enumerate(self.slots.track_ids()):
            if np.isfinite(tid):
                now[(SLOT_IDS, k)] = float(tid)
        conf = np.flatnonzero((ts.status == "confirmed") & (slot >= 0))
        if ts.diagnostics and len(conf):
            row_of = {int(i): r for r, i in enumerate(ts.diagnostic_ids)}
            pairs = [(row_of[int(ts.ids[k])], int(slot[k])) for k in conf if int(ts.ids[k]) in row_of]
            for name, values in ts.diagnostics.items():
                path = series_path(name)
                for r, k in pairs:
                    v = float(values[r])
                    if np.isfinite(v):
                        now[(path, k)] = v
        for key in self.drawing - now.keys():  # drawn in the last frame, not in this one: a gap
            now[key] = np.nan
        self.drawing = {key for key, v in now.items() if np.isfinite(v)}
        for key, v in now.items():
            f, tm, vs = self.series.setdefault(key, ([], [], []))
            f.append(int(truth.frame)); tm.append(float(truth.time)); vs.append(v)

    def _flush_series(self) -> None:
        """Send the buffered diagnostics and metrics, one column per series; a slot's line gets its legend name
        and its slot's colour once."""
        for (path, k), (f, tm, vs) in self.series.items():
            entity = f"{path}/{k}"
            if entity not in self.named:
                name = "track id" if path == SLOT_IDS else path.rsplit("/", 1)[1]
                self.rec.log(entity, rr.SeriesLines(names=series_label(name, k), colors=colours([k])),
                             static=True)
                self.named.add(entity)
            self._send(entity, f, tm, vs)
        for name, (f, tm, vs) in self.metrics.items():
            self._send(f"metrics/{name}", f, tm, vs)
        self.series, self.metrics = {}, {}
        self.series_frames = 0

    def _send(self, path: str, f: list[int], tm: list[float], vs: list[float]) -> None:
        if f:
            self.rec.send_columns(path, indexes=[rr.TimeColumn("frame", sequence=f),
                                                 rr.TimeColumn("sim_time", duration=tm)],
                                  columns=rr.Scalars.columns(scalars=vs))

    def close(self) -> None:
        """Send the buffered series, flush the recording to its file, release it and start its compaction
        (testbed/recording/rrd.py, in its own process: :meth:`wait_compacted`); rerun's errors are raised
        (a RuntimeError when its file writer failed). rerun works in a helper (daemon) thread: if the file does
        not grow for :data:`CLOSE_STALL_S` seconds before it is done, the recording is given up on with a
        TimeoutError and rerun's exit-time flush is switched off (it would wait on this recording forever), so
        the process can still exit."""
        failure: list[BaseException] = []
        done = threading.Event()  # not Thread.join: a join interrupted by a signal marks the thread as ended
        try:
            threading.Thread(target=self._finish, args=(failure, done), name="rerun-close", daemon=True).start()
            _wait_while_growing(done, self.path, CLOSE_STALL_S)
        finally:
            if not done.is_set():  # stuck, or the wait was interrupted (Ctrl-C, SIGTERM): never wait at exit
                rr.unregister_shutdown()
        if not done.is_set():
            raise TimeoutError(f"no progress for {CLOSE_STALL_S:g} s, given up")
        if failure:
            raise failure[0]
        if self.compact:
            self.compaction = rrd.Compaction(self.path)

    def wait_compacted(self) -> None:
        """Wait for the compaction that :meth:`close` started; if it failed, the file stays as written and a
        RuntimeWarning says why. Nothing to do when there is none (or it was waited for)."""
        compaction, self.compaction = self.compaction, None
        why = compaction.wait() if compaction is not None else None
        if why:
            warnings.warn(f"{self.path}: kept as written, not compacted ({why}); it opens slowly in the web "
                          "viewer", RuntimeWarning, stacklevel=2)

    def cancel_compaction(self) -> None:
        """Stop a compaction still running (the file stays as written)."""
        compaction, self.compaction = self.compaction, None
        if compaction is not None:
            compaction.cancel()

    def _finish(self, failure: list[BaseException], done: threading.Event) -> None:
        """Flush and release the recording (in close's helper thread); an exception is put in ``failure``."""
        try:
            try:
                self._flush_series()
                self.rec.flush()
            finally:  # a failed flush (full disk) still releases the recording, so rerun logs its cause
                self.rec.disconnect()
        except BaseException as err:  # noqa: BLE001 - raised again by close() in the caller's thread
            failure.append(err)
        finally:
            done.set()


def static_size(folder: str | Path) -> int:
    """Bytes of a recording with no frame (its blueprint, legend and series styles), written in ``folder``: what a
    run's ``run.rrd`` holds before its first frame (about 0.2 MB)."""
    path = Path(folder) / "static.rrd"
    Recorder(path, "static").close()
    return path.stat().st_size


def perception_stats(truth, scan, perception, detections, max_range_m: float) -> dict[str, float]:
    """One frame's perception statistics measured against the scan's truth labels (NaN, a gap in the plot,
    where undefined): ground precision and recall, P_D of the vehicles within ``max_range_m``, merged and
    split detections, rejected objects."""
    gt = scan.source == GROUND_LABEL
    g = perception.is_ground
    tp = int(np.count_nonzero(g & gt))
    rel = truth.xy[1:] - scan.origin[:2]
    in_range = truth.ids[1:][np.hypot(rel[:, 0], rel[:, 1]) <= max_range_m]
    return dict(ground_precision=tp / int(g.sum()) if g.any() else np.nan,
                ground_recall=tp / int(gt.sum()) if gt.any() else np.nan,
                pd_in_range=float(np.isin(in_range, detections.provenance).mean()) if len(in_range) else np.nan,
                merged_detections=float(np.count_nonzero(detections.flags & sensors.MERGED)),
                split_detections=float(np.count_nonzero(detections.flags & sensors.SPLIT)),
                rejected_objects=float(len(perception.rejected)))


def _wait_while_growing(done: threading.Event, path: Path, stall_s: float) -> None:
    """Wait until ``done`` is set, giving up once the file ``path`` has not grown for ``stall_s`` seconds."""
    size, since = -1, time.monotonic()
    while not done.wait(CLOSE_POLL_S):
        try:
            now_size = os.stat(path).st_size
        except OSError:
            now_size = -1
        if now_size != size:
            size, since = now_size, time.monotonic()
        elif time.monotonic() - since >= stall_s:
            return
