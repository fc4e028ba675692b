"""rerun recording of a run: one ``.rrd`` with a default blueprint and stable entity paths.

Entity paths (all in the world frame, z up, metres):

=================================  ==========================================================
``world/road/lanes``               lane borders (static LineStrips3D)
``world/roadside``                 roadside objects (static Boxes3D)
``world/truth/vehicles``           true vehicle boxes, labelled with their ids (Boxes3D)
``world/truth/ego``                the sensor car (Boxes3D)
``world/ego``                      the sensor car's pose (Transform3D; the camera follows it)
``world/lidar/ground``             ground points, decimated (Points3D, grey)
``world/lidar/objects``            non-ground points, coloured by detection (grey: noise or rejected); hover shows
                                   each point's truth ``vehicle_id`` (-1 static object, -2 road) and ``detection``
``world/lidar/truth``              the same points coloured by truth: vehicle, static object, road (class ids)
``world/lidar/ground_errors``      points the ground segmentation got wrong (red: object called road; magenta:
                                   road called object)
``world/lidar/shadows``            regions hidden behind nearer objects, from the range image (LineStrips3D)
``world/detections``               detections: green from a vehicle, red clutter (Points3D)
``world/detections/boxes``         fitted vehicle boxes: magenta merged fragments, cyan split from a larger
                                   cluster, yellow completed beyond the points (one face seen) (Boxes3D)
``world/detections/rejected``      objects the selection removed, labelled with the test they failed (Points3D)
``world/tracks/confirmed``         confirmed track estimates, labelled T<id> (Points3D)
``world/tracks/tentative``         tentative track estimates (Points3D)
``world/tracks/static``            confirmed tracks not seen to move (moving-object test), not reported (Points3D)
``world/tracks/velocity``          confirmed track velocity over 1 s (Arrows3D)
``world/tracks/covariance``        2-sigma position covariance ellipses (LineStrips3D)
``world/tracks/gates``             validation gates of the predicted tracks (LineStrips3D)
``world/tracks/trajectories``      estimated trajectories of confirmed tracks (LineStrips3D)
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
from pathlib import Path

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

import sensors

from ..common.safe_io import refuse_link

GROUND_LABEL = sensors.GROUND

APP_ID = "roadtrack"
METRICS = ("tracks_confirmed", "tracks_tentative", "tracks_static", "detections", "clutter_detections",
           "lidar_points", "ground_precision", "ground_recall", "pd_in_range", "merged_detections",
           "split_detections", "rejected_objects")
TRUTH_CLASSES = ((0, "road", (90, 90, 90)), (1, "vehicle", (40, 200, 90)), (2, "static object", (160, 110, 60)))
TRAJECTORY_POINTS = 300
CLOSE_STALL_S = 30.0
"""Seconds :meth:`Recorder.close` waits for rerun to flush and release the file while the file does not grow.
rerun 0.41 can block forever in ``flush()`` and ``disconnect()`` once its file writer died on a full disk (an
upstream race, seen in CI): the recording is then given up on, so a run ends with its one line within this
bound. A slow disk that is still being written is waited for."""
CLOSE_POLL_S = 0.5  # how often close() looks at the file's size
SERIES_FLUSH_FRAMES = 200  # per-track diagnostic series are buffered and sent in columns every N frames
FOOTER_MAX_FRAMES = 1200
"""Recordings of up to this many frames end with an rrd footer (a manifest of every chunk, for random access).
rerun keeps that manifest in memory until the file is closed: ~17 kB per frame here (about 3.5 chunks a
frame), 200 MB for a 20-minute run. Longer runs are written without it, as rerun advises for long streams;
``rerun rrd optimize`` adds one afterwards."""
CLUSTER_PALETTE = np.array([[230, 159, 0], [86, 180, 233], [0, 158, 115], [240, 228, 66], [0, 114, 178],
                            [213, 94, 0], [204, 121, 167], [170, 170, 255]], dtype=np.uint8)


def ellipses(centers: np.ndarray, covs: np.ndarray, scale: float, z: float, n: int = 36) -> list[np.ndarray]:
    """Polylines (n+1, 3) of the ellipses ``{c + scale * L u : |u| = 1}``, ``covs`` (T, 2, 2)."""
    if len(centers) == 0:
        return []
    t = np.linspace(0.0, 2 * np.pi, n + 1)
    circle = np.stack([np.cos(t), np.sin(t)])  # (2, n+1)
    w, v = np.linalg.eigh(0.5 * (covs + np.swapaxes(covs, -1, -2)))
    axes = v * np.sqrt(np.clip(w, 0.0, None))[:, None, :]  # (T, 2, 2)
    pts = centers[:, :, None] + scale * axes @ circle  # (T, 2, n+1)
    out = np.concatenate([pts, np.full((len(centers), 1, n + 1), z)], axis=1)
    return list(np.swapaxes(out, 1, 2))


def blueprint(ego_xy: np.ndarray | None = None) -> rrb.Blueprint:
    """Scene on the left, following the ego car from behind and above; counts on the right."""
    eye = None
    if ego_xy is not None:
        x, y = float(ego_xy[0]), float(ego_xy[1])
        eye = rrb.EyeControls3D(kind=rrb.Eye3DKind.Orbital, position=[x - 45.0, y - 30.0, 35.0],
                                look_target=[x + 15.0, y, 0.0], eye_up=[0.0, 0.0, 1.0],
                                tracking_entity="/world/ego")
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(name="scene", origin="/world", eye_controls=eye,
                              overrides={"world/lidar/truth": rrb.EntityBehavior(visible=False)}),
            rrb.Vertical(
                rrb.TimeSeriesView(name="tracks", origin="/metrics",
                                   contents=["/metrics/tracks_confirmed", "/metrics/tracks_tentative"]),
                rrb.TimeSeriesView(name="detections", origin="/metrics",
                                   contents=["/metrics/detections", "/metrics/clutter_detections"]),
                rrb.TimeSeriesView(name="perception (measured against truth)", origin="/metrics",
                                   contents=["/metrics/ground_precision", "/metrics/ground_recall",
                                             "/metrics/pd_in_range"]),
                rrb.TimeSeriesView(name="merged / split / rejected", origin="/metrics",
                                   contents=["/metrics/merged_detections", "/metrics/split_detections",
                                             "/metrics/rejected_objects"]),
                rrb.TimeSeriesView(name="track diagnostics (score, NIS, layers, mode probabilities)",
                                   origin="/world/tracks"),
            ),
            column_shares=[3, 1],
        ),
        rrb.BlueprintPanel(state="collapsed"),
        rrb.SelectionPanel(state="collapsed"),
        rrb.TimePanel(state="collapsed"),
    )


def _boxes(centers_xy, size, yaw, z_bottom=None) -> dict:
    size = np.asarray(size, dtype=np.float64).reshape(-1, 3)
    zb = np.zeros(len(size)) if z_bottom is None else np.asarray(z_bottom, dtype=np.float64)
    centers = np.column_stack([centers_xy, zb + size[:, 2] / 2])
    return dict(centers=centers, half_sizes=size / 2,
                rotation_axis_angles=[rr.RotationAxisAngle(axis=[0, 0, 1], radians=float(a)) for a in yaw])


class Recorder:
    """Writes one run to ``path`` (``.rrd``). Call :meth:`static` once, :meth:`frame` per frame, :meth:`close`."""

    def __init__(self, path: str | Path, recording_id: str, lidar_every: int = 1, ground_decimation: int = 4,
                 write_footer: bool = True, occlusion: sensors.OcclusionConfig | None = None,
                 max_range_m: float = 70.0):
        self.path = Path(path)
        self.occlusion = occlusion  # draw the occluders' shadows with it (None: no shadows)
        self.max_range_m = max_range_m
        self.lidar_every = lidar_every
        self.ground_decimation = ground_decimation
        refuse_link(self.path)  # rerun opens it following links: a planted one is refused, never written through
        self.rec = rr.RecordingStream(APP_ID, recording_id=recording_id)
        self.rec.save(str(self.path), write_footer=write_footer)  # see FOOTER_MAX_FRAMES
        self.blueprint_sent = False
        self.rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        self.rec.log("world/lidar", rr.AnnotationContext(
            [rr.AnnotationInfo(id=i, label=name, color=c) for i, name, c in TRUTH_CLASSES]), static=True)
        for name in METRICS:
            self.rec.log(f"metrics/{name}", rr.SeriesLines(names=name.replace("_", " ")), static=True)
        self.trajectories: dict[int, list[np.ndarray]] = {}
        self.series: dict[tuple[int, str], tuple[list[int], list[float], list[float]]] = {}
        self.series_frames = 0
        self.layers_logged = False

    def static(self, lanes: list[np.ndarray], roadside: np.ndarray) -> None:
        """Road lane borders (list of (P, 2)) and roadside boxes (K, 7) [cx, cy, L, W, H, yaw, z_bottom]."""
        strips = [np.column_stack([ln, np.zeros(len(ln))]) for ln in lanes]
        self.rec.log("world/road/lanes", rr.LineStrips3D(strips, colors=[200, 200, 200], radii=0.05), static=True)
        if len(roadside):
            self.rec.log("world/roadside", rr.Boxes3D(**_boxes(roadside[:, :2], roadside[:, 2:5], roadside[:, 5],
                                                               roadside[:, 6]), colors=[120, 120, 120]), static=True)

    def frame(self, truth, scan, perception, detections, ts) -> None:
        """Log one frame. ``ts``: the tracker's testbed.tracking.TrackSet after the step, its status "confirmed",
        "tentative" or "static" (the moving-object test's); its ``info`` (the built-in trackers' StepInfo) adds
        the gates and boundary layers. ``scan`` and ``perception`` may be None (no point cloud is logged)."""
        status = ts.status
        rec = self.rec
        rec.set_time("frame", sequence=int(truth.frame))
        rec.set_time("sim_time", duration=float(truth.time))

        if not self.blueprint_sent:  # the camera starts behind the ego car and follows it
            rec.send_blueprint(blueprint(truth.xy[0]), make_active=True, make_default=True)
            self.blueprint_sent = True
        size = truth.size
        labels = [f"{n} ({i})" for n, i in zip(truth.names, truth.ids)]
        rec.log("world/ego", rr.Transform3D(translation=[truth.xy[0, 0], truth.xy[0, 1], 0.0],
                                            rotation_axis_angle=rr.RotationAxisAngle(axis=[0, 0, 1],
                                                                                     radians=float(truth.heading[0]))))
        rec.log("world/truth/ego", rr.Boxes3D(**_boxes(truth.xy[:1], size[:1], truth.heading[:1]),
                                              labels=labels[:1], colors=[255, 255, 255]))
        rec.log("world/truth/vehicles", rr.Boxes3D(**_boxes(truth.xy[1:], size[1:], truth.heading[1:]),
                                                   labels=labels[1:], class_ids=truth.ids[1:],
                                                   show_labels=False))

        if self.lidar_every and truth.frame % self.lidar_every == 0 and scan is not None:
            self._lidar(scan, perception)
        if scan is not None:
            self._perception_stats(truth, scan, perception, detections)

        z = detections.z
        is_vehicle = detections.provenance >= 0
        rec.log("world/detections", rr.Points3D(
            np.column_stack([z, np.full(len(z), 0.3)]), radii=0.35,
            colors=np.where(is_vehicle[:, None], np.array([40, 220, 40], np.uint8), np.array([230, 40, 40], np.uint8)),
            labels=[f"v{p}" if p >= 0 else "clutter" for p in detections.provenance], show_labels=False))
        self._boxes_and_rejects(detections, perception)

        conf = ts.ids[status == "confirmed"]
        self._tracks(ts)
        self._diagnostics(truth, conf, ts)

        counts = dict(tracks_confirmed=len(conf), tracks_tentative=int(np.count_nonzero(status == "tentative")),
                      tracks_static=int(np.count_nonzero(status == "static")), detections=len(z),
                      clutter_detections=int(np.count_nonzero(~is_vehicle)),
                      lidar_points=0 if scan is None else len(scan.points))
        for name, value in counts.items():
            rec.log(f"metrics/{name}", rr.Scalars(float(value)))

    def _lidar(self, scan, perception) -> None:
        """Ground points, object points with their detection and truth labels, ground errors, shadows."""
        rec = self.rec
        g = perception.is_ground
        pts, src, lab = scan.points[~g], scan.source[~g], perception.labels[~g]
        rec.log("world/lidar/ground", rr.Points3D(scan.points[g][:: self.ground_decimation],
                                                  colors=[90, 90, 90], radii=0.03))
        colors = np.where((lab >= 0)[:, None], CLUSTER_PALETTE[lab % len(CLUSTER_PALETTE)],
                          np.array([200, 200, 200], np.uint8))
        rec.log("world/lidar/objects", rr.Points3D(pts, colors=colors, radii=0.05),
                rr.AnyValues(vehicle_id=src, detection=lab))
        truth_class = np.where(src >= 0, 1, np.where(src == -1, 2, 0))
        rec.log("world/lidar/truth", rr.Points3D(pts, class_ids=truth_class, radii=0.05))
        gt = scan.source == GROUND_LABEL
        wrong_obj, wrong_road = g & ~gt, ~g & gt  # object called road; road called object
        err = np.concatenate([np.flatnonzero(wrong_obj), np.flatnonzero(wrong_road)])
        err_colors = np.concatenate([np.tile([230, 30, 30], (int(wrong_obj.sum()), 1)),
                                     np.tile([230, 0, 230], (int(wrong_road.sum()), 1))]).astype(np.uint8)
        rec.log("world/lidar/ground_errors", rr.Points3D(scan.points[err], colors=err_colors.reshape(-1, 3), radii=0.08))
        if self.occlusion is not None and len(scan.ranges):
            polys = sensors.shadows(scan, self.occlusion, is_ground=perception.is_ground)
            rec.log("world/lidar/shadows", rr.LineStrips3D(
                [np.column_stack([np.vstack([p, p[:1]]), np.full(len(p) + 1, 0.05)]) for p in polys],
                colors=[70, 70, 160], radii=0.04))

    def _boxes_and_rejects(self, detections, perception) -> None:
        """Fitted boxes coloured by their merge / split / completion flags; rejected objects with the reason."""
        rec = self.rec
        f = detections.flags
        color = np.where(detections.provenance[:, None] >= 0, np.array([40, 220, 40]), np.array([230, 40, 40]))
        color = np.where((f & sensors.COMPLETED)[:, None] > 0, np.array([240, 210, 40]), color)
        color = np.where((f & sensors.SPLIT)[:, None] > 0, np.array([0, 210, 230]), color)
        color = np.where((f & sensors.MERGED)[:, None] > 0, np.array([230, 0, 230]), color)
        tags = [" ".join(t for bit, t in ((sensors.MERGED, "merged"), (sensors.SPLIT, "split"),
                                          (sensors.COMPLETED, "completed")) if v & bit) or "box" for v in f]
        size = detections.extent.copy()
        size[:, 2] = np.maximum(size[:, 2], 0.1)
        rec.log("world/detections/boxes", rr.Boxes3D(**_boxes(detections.z, size, detections.heading),
                                                     colors=color.astype(np.uint8), labels=tags, show_labels=False,
                                                     radii=0.03))
        rj = perception.rejected if perception is not None else None
        if rj is not None:
            rec.log("world/detections/rejected", rr.Points3D(
                np.column_stack([rj.centre, np.full(len(rj), 0.5)]), radii=0.2, colors=[150, 110, 70],
                labels=[str(r) for r in rj.reason], show_labels=False))

    def _perception_stats(self, truth, scan, perception, detections) -> None:
        """Per-frame perception statistics measured against the scan's truth labels."""
        gt = scan.source == GROUND_LABEL
        g = perception.is_ground
        tp = int(np.count_nonzero(g & gt))
        rel = truth.xy[1:] - scan.origin[:2]
        in_range = truth.ids[1:][np.hypot(rel[:, 0], rel[:, 1]) <= self.max_range_m]
        stats = dict(  # NaN (a gap in the plot) where undefined
            ground_precision=tp / int(g.sum()) if g.any() else np.nan,
            ground_recall=tp / int(gt.sum()) if gt.any() else np.nan,
            pd_in_range=float(np.isin(in_range, detections.provenance).mean()) if len(in_range) else np.nan)
        stats["merged_detections"] = float(np.count_nonzero(detections.flags & sensors.MERGED))
        stats["split_detections"] = float(np.count_nonzero(detections.flags & sensors.SPLIT))
        stats["rejected_objects"] = float(len(perception.rejected))
        for name, value in stats.items():
            self.rec.log(f"metrics/{name}", rr.Scalars(float(value)))

    def _tracks(self, ts) -> None:
        """Track estimates, velocities, covariance ellipses, gates, boundary layers and trajectories."""
        rec = self.rec
        info, gate_alpha, status = ts.info, ts.gate_alpha, ts.status
        pos, vel, ppos = ts.xy, ts.v, ts.cov[:, :2, :2]
        ids = ts.ids
        regime = ts.regime  # e.g. paper 002's KS regime
        conf = status == "confirmed"
        for name, sel, radius in (("confirmed", conf, 0.5), ("tentative", status == "tentative", 0.25),
                                  ("static", status == "static", 0.35)):
            rec.log(f"world/tracks/{name}", rr.Points3D(
                np.column_stack([pos[sel], np.full(int(sel.sum()), 1.0)]), radii=radius,
                labels=[f"T{i} {r}" for i, r in zip(ids[sel], regime[sel])], class_ids=ids[sel], show_labels=name == "confirmed"))
        rec.log("world/tracks/velocity", rr.Arrows3D(origins=np.column_stack([pos[conf], np.ones(int(conf.sum()))]),
                                                     vectors=np.column_stack([vel[conf], np.zeros(int(conf.sum()))]),
                                                     class_ids=ids[conf]))
        given = np.isfinite(ppos).all(axis=(1, 2))
        rec.log("world/tracks/covariance", rr.LineStrips3D(ellipses(pos[given], ppos[given], 2.0, 1.0),
                                                           class_ids=ids[given], radii=0.04))
        if info is not None and len(info.ids):
            rec.log("world/tracks/gates", rr.LineStrips3D(
                ellipses(info.z_hat, info.S, float(np.sqrt(gate_alpha)), 0.2), class_ids=info.ids, radii=0.03))
        else:
            rec.log("world/tracks/gates", rr.LineStrips3D([]))
        # SVSF boundary layers: a box of the layer's half widths around each updated estimate (thesis §2.1, §3.4)
        where = {int(i): k for k, i in enumerate(ids)}
        rows = [] if info is None else [(k, where[int(i)]) for k, i in enumerate(info.ids)
                                        if int(i) in where and np.isfinite(info.layers[k]).all()]
        if rows or self.layers_logged:
            lk = np.array([r[0] for r in rows], dtype=np.int64)
            tk = np.array([r[1] for r in rows], dtype=np.int64)
            half = info.layers[lk][:, :2] if rows else np.zeros((0, 2))
            rec.log("world/tracks/layers", rr.Boxes3D(
                centers=np.column_stack([pos[tk], np.full(len(tk), 1.0)]) if rows else np.zeros((0, 3)),
                half_sizes=np.column_stack([half, np.full(len(tk), 0.05)]), class_ids=ids[tk] if rows else [],
                colors=[255, 140, 0]))
            self.layers_logged = True
        live = set(ids[conf].tolist())
        for k in np.flatnonzero(conf):
            pts = self.trajectories.setdefault(int(ids[k]), [])
            pts.append(np.array([pos[k, 0], pos[k, 1], 1.0]))
            del pts[:-TRAJECTORY_POINTS]
        for tid in [i for i in self.trajectories if i not in set(ids.tolist())]:
            del self.trajectories[tid]
        rec.log("world/tracks/trajectories", rr.LineStrips3D(
            [np.array(self.trajectories[i]) for i in sorted(live)], class_ids=sorted(live), radii=0.08))

    def _diagnostics(self, truth, conf: np.ndarray, ts) -> None:
        """Buffer the confirmed tracks' (ids ``conf``) diagnostics as series ``world/tracks/<id>/<name>``; sent in
        columns."""
        if not ts.diagnostics:
            return
        row = {int(i): k for k, i in enumerate(ts.diagnostic_ids)}
        for tid in conf:
            k = row.get(int(tid))
            if k is None:
                continue
            for name, values in ts.diagnostics.items():
                v = float(values[k])
                if np.isfinite(v):
                    f, tm, vs = self.series.setdefault((int(tid), name), ([], [], []))
                    f.append(int(truth.frame)); tm.append(float(truth.time)); vs.append(v)
        self.series_frames += 1
        if self.series_frames >= SERIES_FLUSH_FRAMES:
            self._flush_series()

    def _flush_series(self) -> None:
        for (tid, name), (f, tm, vs) in self.series.items():
            if f:
                self.rec.send_columns(f"world/tracks/{tid}/{name}",
                                      indexes=[rr.TimeColumn("frame", sequence=f),
                                               rr.TimeColumn("sim_time", duration=tm)],
                                      columns=rr.Scalars.columns(scalars=vs))
        self.series = {}
        self.series_frames = 0

    def close(self) -> None:
        """Send the buffered series, flush the recording to its file and release it; rerun's errors are raised
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
