"""One run of a scenario: traffic -> LiDAR -> ground -> clusters -> detections -> tracker -> scores.

``run_scenario`` is the whole loop; the CLI, the tests and the benchmark call it. Random streams derive
from the scenario seed (``SeedSequence(seed).spawn``), one per consumer, so switching on added clutter
does not change the LiDAR noise.
"""
from __future__ import annotations

import errno
import os
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

import sensors

from .config import to_dict
from .jsonio import json_text
from .mot_metrics import mot_metrics, visible_truth
from .moving import MovingTest
from .outdir import write_atomic
from .roadside import boxes_near
from .scenario import Scenario
from .scoring import Scores, score_run
from .simulation import lane_centres, lane_polylines, roadside_objects
from .tables import diagnostics_log, detections_log, tracks_log, truth_log

STAGES = ("simulation", "raycast", "perception", "tracking", "recording")
STREAMS = ("roadside", "lidar", "clutter")


@dataclass
class RunResult:
    scenario: Scenario
    scores: Scores
    timings_ms: dict[str, float]          # mean ms per frame per stage
    n_frames: int
    out_dir: Path | None
    tables: dict = field(default_factory=dict)  # name -> TableLog
    metrics: dict[str, float] = field(default_factory=dict)  # standard MOT metrics (HOTA, MOTA, IDF1, GOSPA)

    def summary(self) -> dict[str, float]:
        """Flat dict of every scalar score of the run: thesis scores, MOT metrics, ms per frame per stage."""
        out = dict(self.scores.to_dict())
        out.update(self.metrics)
        out.update({f"ms_{k}": v for k, v in self.timings_ms.items()})
        return out


def rng_streams(seed: int) -> dict[str, np.random.Generator]:
    """Independent generators, one per consumer, derived from the scenario seed."""
    seqs = np.random.SeedSequence(seed).spawn(len(STREAMS))
    return {name: np.random.default_rng(s) for name, s in zip(STREAMS, seqs)}


def run_scenario(scn: Scenario, out_dir: str | Path | None = None, record: bool = True,
                 tracker_name: str | None = None,
                 on_frame: Callable[[int, int], None] | None = None, policy: Callable | None = None) -> RunResult:
    """Run ``scn``; with ``out_dir`` write scores.json, the parquet tables and (``record``) run.rrd, each file
    atomically (complete or absent).

    On any exception, Ctrl-C included, the recording is closed and the tables of the frames done are written
    before it propagates, with a note saying where the run stopped. JPDA overflow warnings (one per oversize
    cluster) are counted and given once at the end of the run. ``policy``: the ego's policy
    ``f(observation, info) -> action`` for a scenario with ``[env]`` (testbed/envsource.py), replacing the
    file's built-in one."""
    name = tracker_name or scn.tracker.name
    tracker = scn.tracker.build(name)
    rngs = rng_streams(scn.seed)
    sim, static, road = sensing_setup(scn, rngs, policy)
    out = Path(out_dir) if out_dir is not None else None
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
    recorder = _recorder(scn, out / "run.rrd", name, sim, static) if out is not None and record else None
    tables = dict(truth=truth_log(), detections=detections_log(), tracks=tracks_log(), diagnostics=diagnostics_log())
    watch = Stopwatch()
    state = _Progress()
    overflows = _Overflows()
    try:
        _frames(scn, tracker, sim, static, road, rngs, recorder, tables, watch, state, overflows, on_frame)
        state.looping = False
        if recorder is not None:
            t0 = time.perf_counter()
            closing, recorder = recorder, None  # closed once, even if closing fails
            _close_recording(closing)
            watch.spent["recording"] += time.perf_counter() - t0
        scores, metrics = score_tables(scn, tables["truth"], tables["tracks"], state.frames)
        timings = {k: 1000.0 * v / max(state.frames, 1) for k, v in watch.spent.items()}
        res = RunResult(scn, scores, timings, state.frames, out, tables, metrics)
        if out is not None:
            _write_tables(out, tables)
            state.tables_written = True
            write_scores(res, name)
    except BaseException as err:  # keep what was computed: the tables of the frames before the failure
        _keep_partial(err, scn, state, recorder, out, tables)
        raise
    finally:
        overflows.report()
    return res


@dataclass
class _Progress:
    """Where a run is: frames done, whether still in the frame loop, whether its tables are written."""

    frames: int = 0
    looping: bool = True
    tables_written: bool = False
    rows: dict[str, int] = field(default_factory=dict)  # each table's rows at the end of the last frame done


def _frames(scn, tracker, sim, static, road, rngs, recorder, tables, watch, state: _Progress, overflows,
            on_frame) -> None:
    """The frame loop: sense, track, log; ``state.frames`` counts the frames done."""
    pd_input = occlusion_pd(scn, tracker.association.pd, road) if scn.sensor.occlusion_pd else None
    moving = MovingTest(scn.moving_test)
    tracks: tuple = ()
    next_id = 1
    trucks: dict[int, bool] = {}
    for truth in sim.frames():
        watch.lap("simulation")
        scan, perc, dets = sense_frame(truth, static, scn, rngs, watch, road)
        live = np.array([trucks.get(t.id, False) for t in tracks if not t.candidate], dtype=bool)
        pd = pd_input(scan, live) if pd_input is not None else None
        result = overflows.call(tracker.step, tracks, dets.z, scn.dt if truth.frame > 0 else 0.0, next_id, pd=pd)
        tracks, next_id = result.tracks, result.next_id
        if pd_input is not None:
            alive = {t.id for t in tracks}
            trucks = {k: v for k, v in truck_tracks(result.info.ids, result.info.W, dets.extent[:, 0], trucks).items()
                      if k in alive}
        reported = tuple(t for t in tracks if not t.candidate)  # candidates await a second measurement
        kin = tracker.kinematics(reported)
        status = track_status(reported, kin, moving, truth.time)
        watch.lap("tracking")
        log_tables(truth, visibility(truth, scan, scn.sensor.lidar.max_range_m), dets, reported, kin, status,
                    tables["truth"], tables["detections"], tables["tracks"])
        log_diagnostics(truth, result.info, tables["diagnostics"])
        if recorder is not None:
            recorder.frame(truth, scan, perc, dets, reported, kin, result.info, tracker.association.gate_alpha,
                           status)
        watch.lap("recording")
        state.rows = {k: log.n_rows for k, log in tables.items()}
        state.frames += 1
        if on_frame is not None:
            on_frame(state.frames, scn.n_frames)


def _keep_partial(err: BaseException, scn: Scenario, state: _Progress, recorder, out: Path | None,
                  tables: dict) -> None:
    """After a failure: note where the run stopped on ``err``, close the recording, write the tables (best
    effort: an error here is noted, never raised over ``err``)."""
    n = state.frames
    if state.looping:
        err.add_note(f"the run stopped at frame {n} (t = {n * scn.dt:.1f} s)")
    else:
        err.add_note(f"the run had done its {n} frames")
    if recorder is not None:
        try:
            _close_recording(recorder)
        except (Exception, KeyboardInterrupt) as close_err:  # noqa: BLE001 - err is the one to report
            err.add_note(f"the recording could not be closed ({_short_cause(close_err)})")
    if out is not None and not state.tables_written:
        if state.looping:  # a frame cut short (e.g. a signal between its tables) is dropped from all of them
            for k, log in tables.items():
                log.truncate(state.rows.get(k, 0))
        try:
            _write_tables(out, tables)
        except (Exception, KeyboardInterrupt) as write_err:  # noqa: BLE001
            err.add_note(f"the tables could not be written ({_short_cause(write_err)})")


def _short_cause(err: BaseException) -> str:
    """A short cause: ``no space left on device`` for an OSError, else ``Type: message``."""
    from .errors import one_line

    if isinstance(err, OSError) and err.errno:
        return os.strerror(err.errno).lower()
    return f"{type(err).__name__}: {one_line(err)}"


LOW_SPACE_BYTES = 1 << 20
"""Free space below which a recording that rerun could not finish is reported as a full disk."""


def _close_recording(recorder) -> None:
    """Close the recording, within a bound (:data:`testbed.recording.CLOSE_STALL_S` without progress). rerun's
    file writer stopping early (it has logged why; ours is then the last line) or rerun not finishing is raised
    as an OSError ENOSPC naming the file when its disk is (nearly) full, else as a RunError."""
    from .errors import RunError, one_line

    try:
        recorder.close()  # it also releases the recording when the flush failed (not when rerun is stuck)
    except (RuntimeError, TimeoutError) as err:  # TimeoutError: rerun blocked, given up on
        path = Path(recorder.path)
        try:
            st = os.statvfs(path.parent)
            full = st.f_bavail * st.f_frsize < LOW_SPACE_BYTES
        except OSError:
            full = False
        if full:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path)) from err
        raise RunError(f"{path}: the recording could not be written (rerun: {one_line(err)}; rerun's log "
                       f"above says why)") from err


class _Overflows:
    """JPDA overflow warnings of a run (one per oversize cluster and frame), given once at the end with a
    count; other warnings of the tracker pass through (each once per run)."""

    def __init__(self):
        self.frames = 0
        self.clusters = 0
        self.largest = (0, 0)  # (tracks, measurements) of the largest cluster (by tracks x measurements)
        self.registry: dict = {}

    def call(self, func, *args, **kwargs):
        from trackers import JPDAOverflowWarning

        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", JPDAOverflowWarning)  # counted here, not shown one by one
            out = func(*args, **kwargs)
        mine = [w for w in caught if issubclass(w.category, JPDAOverflowWarning)]
        for w in caught:
            if not issubclass(w.category, JPDAOverflowWarning):
                warnings.warn_explicit(w.message, w.category, w.filename, w.lineno, registry=self.registry,
                                       source=w.source)
        if mine:
            self.frames += 1
            self.clusters += len(mine)
            for w in mine:
                size = (getattr(w.message, "tracks", 0), getattr(w.message, "measurements", 0))
                self.largest = max(self.largest, size, key=lambda tm: tm[0] * tm[1])
        return out

    def report(self) -> None:
        from trackers import JPDAOverflowWarning

        if self.frames:
            t, m = self.largest
            plural = "s" if self.frames > 1 else ""
            warnings.warn(JPDAOverflowWarning(
                f"JPDA: {self.frames} frame{plural} exceeded max_events ({self.clusters} clusters, the largest "
                f"{t} tracks x {m} measurements); those clusters used per-track PDA"), stacklevel=3)


class Stopwatch:
    """Seconds spent per stage: ``lap(stage)`` charges the time since the previous lap to ``stage``."""

    def __init__(self):
        self.spent = dict.fromkeys(STAGES, 0.0)
        self.tic = time.perf_counter()

    def lap(self, stage: str) -> None:
        now = time.perf_counter()
        self.spent[stage] += now - self.tic
        self.tic = now


def sensing_setup(scn: Scenario, rngs: dict[str, np.random.Generator], policy: Callable | None = None):
    """The traffic source of ``scn`` (a highway-env environment with ``[env]``, its ego driven by ``policy`` when
    given, else our scripted traffic), its roadside boxes (K, 7) drawn from ``rngs["roadside"]`` and the
    perception's road map."""
    from .envsource import make_simulation

    sim = make_simulation(scn, policy)
    static = roadside_objects(sim.network, scn.roadside, rngs["roadside"])
    return sim, static, road_map(sim.network)


def road_map(network) -> sensors.RoadMap:
    """The perception's road map (lane centre lines and half widths) of a highway-env road network."""
    return sensors.RoadMap(*lane_centres(network))


TRUCK_BOX_M = (15.4, 2.5, 3.5)
"""(length, width, height) [m] of the truck box of the occlusion-aware P_D: the box fit's truck prior
(sensors/boxfit.py); the rear face of a 12-18.75 m truck lies within the 2 m margin of its entry."""


TRUCK_MIN_LENGTH_M = 7.0
"""A detection longer than this [m] is a truck's (the box fit's truck boxes are at least 7.5 m long)."""


def truck_tracks(ids: np.ndarray, W: np.ndarray, lengths: np.ndarray, known: dict[int, bool]) -> dict[int, bool]:
    """``known`` (track id -> truck) updated from one step: a track whose association weight W (T, M) on one
    detection exceeds 1/2 takes that detection's class (``lengths`` (M,) [m] > :data:`TRUCK_MIN_LENGTH_M`)."""
    out = dict(known)
    if W.size:
        best = np.argmax(W, axis=1)
        for t in np.flatnonzero(W[np.arange(len(ids)), best] > 0.5):
            out[int(ids[t])] = bool(lengths[best[t]] > TRUCK_MIN_LENGTH_M)
    return out


def occlusion_pd(scn: Scenario, pd: float, road: sensors.RoadMap):
    """The tracker's per-track P_D input, per scan: ``occlusion_pd(...)(scan)`` is a function of the predicted
    positions (T, 2) -> (T,).

    Within the sensor's range: the associator's nominal ``pd`` where the range image shows a car-sized box at
    the position (heading along the road) in view, near 0 (at least ``sensor.occlusion_pd_floor``) in the
    shadow of a nearer object or where no beam reaches a car (sensors/occlusion.py): a hidden car's track
    coasts without losing score. Beyond the range: the nominal ``pd``, so a track leaving the sensor's reach
    loses score and is deleted as without this input (a P_D of 0 there would keep it forever).

    ``for_scan(scan, trucks)``: ``trucks`` (T,) bool marks the tracks whose last associated detection was
    truck-long (:func:`truck_tracks`); their P_D is that of a truck-sized box (:data:`TRUCK_BOX_M`). With the
    car box a truck's own rear face, 6-9 m before its centre and so nearer than a car box's entry, "blocked"
    the view of it: a truck 20 m behind, hit by 1000 points a scan, got P_D 0 and its track was never updated.
    (A truck box for every track would not do: the car just ahead of a hidden car then lies at the box's
    entry and no longer hides it.)"""
    lidar = scn.sensor.lidar
    cfg = sensors.OcclusionConfig.from_lidar(lidar, pd_nominal=pd, min_points=scn.sensor.perception.cluster.min_points)
    floor = min(scn.sensor.occlusion_pd_floor, pd)

    def for_scan(scan: sensors.Scan, trucks: np.ndarray | None = None):
        def pd_of(z_hat: np.ndarray) -> np.ndarray:
            xy = z_hat[:, :2]
            heading = road.heading_at(xy) if len(xy) else None
            occ = sensors.detection_probability(scan, xy, cfg, heading=heading)
            if trucks is not None and trucks.any():
                occ[trucks] = sensors.detection_probability(scan, xy[trucks], cfg, size_m=TRUCK_BOX_M,
                                                            heading=None if heading is None else heading[trucks])
            beyond = np.hypot(xy[:, 0] - scan.origin[0], xy[:, 1] - scan.origin[1]) > lidar.max_range_m
            return np.where(beyond, pd, np.maximum(occ, floor))

        return pd_of

    return for_scan


def track_status(tracks: tuple, kin: tuple[np.ndarray, np.ndarray], moving: MovingTest, time: float) -> np.ndarray:
    """(T,) object array: "confirmed" (reported), "tentative", or "static" (confirmed by the tracker but
    not yet seen to move, testbed/moving.py: tracked, not reported, not scored)."""
    ids = np.array([t.id for t in tracks], dtype=np.int64)
    moved = moving.update(ids, kin[0][:, :2], time)
    conf = np.array([t.confirmed for t in tracks], dtype=bool)
    return np.where(conf, np.where(moved, "confirmed", "static"), "tentative").astype(object)


def sense_frame(truth, static: np.ndarray, scn: Scenario, rngs: dict, watch: Stopwatch, road: sensors.RoadMap | None):
    """One frame's LiDAR scan, perception and detections (plus the scenario's added clutter).

    ``sensor.outages``: the named vehicles are left out of the ray-cast scene; while the whole sensor is off the
    scan is cast (so the noise streams stay aligned with a run without the outage) and then emptied, and the
    added clutter is drawn and dropped."""
    off, hidden = scn.sensor.outage_at(truth.time)
    scan = scan_frame(truth, static, scn.sensor.lidar, rngs["lidar"], hidden=hidden)
    if off:
        scan = empty_scan(scan)
    watch.lap("raycast")
    perc = sensors.perceive(scan, scn.sensor.perception, road)
    dets = perc.detections
    clutter = scn.sensor.clutter
    if clutter.density_per_m2 > 0:
        extra = sensors.clutter_detections(rngs["clutter"], clutter.density_per_m2, truth.xy[0], clutter.radius_m)
        dets = dets if off else dets.concat(extra)
    watch.lap("perception")
    return scan, perc, dets


def empty_scan(scan: sensors.Scan) -> sensors.Scan:
    """``scan`` with no points and a range image of inf (no ray returned): a sensor outage. The occlusion-aware
    P_D of such a scan is nominal everywhere in range (nothing hides anything)."""
    return sensors.Scan(points=np.zeros((0, 3)), source=np.zeros(0, dtype=np.int64), origin=scan.origin,
                        ranges=np.full_like(scan.ranges, np.inf), ray=np.zeros(0, dtype=np.int64),
                        azimuths=scan.azimuths, elevations=scan.elevations, pose=scan.pose)


def scan_frame(truth, static: np.ndarray, cfg: sensors.LidarConfig, rng: np.random.Generator,
          hidden: frozenset[str] = frozenset()) -> sensors.Scan:
    """One LiDAR turn from the ego car at the vehicles (ego left out) and roadside boxes within reach; the
    vehicles named in ``hidden`` are left out of the scene (a forced loss: no return, no shadow)."""
    reach = cfg.max_range_m + 10.0
    boxes, ids = truth.boxes()
    cars = boxes_near(boxes, truth.xy[0], reach)  # a car beyond the LiDAR's reach returns no point
    if hidden:
        cars &= np.array([n not in hidden for n in truth.names[1:]], dtype=bool)
    near = boxes_near(static, truth.xy[0], reach)
    scene_boxes = np.vstack([boxes[cars], static[near]])
    scene_ids = np.concatenate([ids[cars], np.full(int(near.sum()), -1, dtype=np.int64)])
    return sensors.scan(cfg, truth.ego_pose, scene_boxes, scene_ids, rng)


def _recorder(scn: Scenario, path: Path, tracker_name: str, sim, static: np.ndarray):
    """A :class:`~testbed.recording.Recorder` with the road and roadside objects logged."""
    from .recording import FOOTER_MAX_FRAMES, Recorder  # rerun is imported only when recording

    rec = Recorder(path, recording_id=f"{scn.name}-seed{scn.seed}-{tracker_name}",
                   lidar_every=scn.record.lidar_every, ground_decimation=scn.record.ground_decimation,
                   write_footer=scn.n_frames <= FOOTER_MAX_FRAMES,
                   occlusion=sensors.OcclusionConfig.from_lidar(scn.sensor.lidar), max_range_m=scn.sensor.lidar.max_range_m)
    rec.static(lane_polylines(sim.network), static)
    return rec


def visibility(truth, scan, max_range_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Per vehicle of ``truth`` (K,): LiDAR points that hit it (int64) and whether its centre lies
    within ``max_range_m`` of the sensor (bool)."""
    ids, counts = np.unique(scan.source[scan.source >= 0], return_counts=True)
    n_points = np.zeros(len(truth.ids), dtype=np.int64)
    if len(ids):
        at = np.minimum(np.searchsorted(ids, truth.ids), len(ids) - 1)
        hit = ids[at] == truth.ids
        n_points[hit] = counts[at[hit]]
    in_range = np.hypot(*(truth.xy - scan.origin[:2]).T) <= max_range_m
    return n_points, in_range


def score_tables(scn: Scenario, truth_t, trk_t, n_frames: int) -> tuple[Scores, dict[str, float]]:
    """Thesis scores and the MOT metrics (visible truth, and all truth as ``*_all``) of a run's tables."""
    keep = ~truth_t.array("is_ego")
    sc = scn.scoring
    truth = dict(frame=truth_t.array("frame")[keep], vehicle_id=truth_t.array("vehicle_id")[keep],
                 xy=np.column_stack([truth_t.array("x"), truth_t.array("y")])[keep],
                 v=np.column_stack([truth_t.array("vx"), truth_t.array("vy")])[keep],
                 visible=truth_t.array("n_points")[keep] >= sc.visible_min_points)
    tracks = dict(frame=trk_t.array("frame"), track_id=trk_t.array("track_id"),
                  confirmed=trk_t.array("status") == "confirmed",
                  xy=np.column_stack([trk_t.array("x"), trk_t.array("y")]),
                  v=np.column_stack([trk_t.array("vx"), trk_t.array("vy")]))
    scores = score_run(truth, tracks, match_distance_m=sc.match_distance_m, correct_fraction=sc.correct_fraction)
    conf = tracks["confirmed"]
    scale = sc.similarity_scale_m or sc.match_distance_m
    g_all = {k: truth[k] for k in ("frame", "vehicle_id", "xy", "visible")}
    t_all = {k: tracks[k][conf] for k in ("frame", "track_id", "xy")}
    g_vis, t_vis = visible_truth(g_all, t_all, scale)
    kw = dict(similarity_scale_m=scale, gospa_c=sc.match_distance_m)
    metrics = mot_metrics(g_vis, t_vis, n_frames, **kw)
    metrics.update({f"{k}_all": v for k, v in mot_metrics(g_all, t_all, n_frames, **kw).items()})
    return scores, metrics


def log_diagnostics(truth, info, diag_t) -> None:
    """Long format: one row per (track, quantity) of the step's diagnostics (NIS, gate volume, the filters'
    boundary layers and mode probabilities, the associator's extras)."""
    T = len(info.ids)
    if not T or not info.diagnostics:
        return
    names = sorted(info.diagnostics)
    values = np.stack([np.asarray(info.diagnostics[k], dtype=np.float64) for k in names], axis=1)  # (T, N)
    keep = np.isfinite(values)
    rows, cols = np.nonzero(keep)
    diag_t.append(frame=np.full(rows.size, truth.frame), time=np.full(rows.size, truth.time),
                  track_id=info.ids[rows], name=np.array(names, dtype=object)[cols], value=values[rows, cols])


def log_tables(truth, vis, dets, tracks, kin, status, truth_t, det_t, trk_t) -> None:
    k = len(truth.ids)
    truth_t.append(frame=np.full(k, truth.frame), time=np.full(k, truth.time), vehicle_id=truth.ids,
                   name=np.array(truth.names, dtype=object), is_ego=truth.ids == truth.ids[0],
                   x=truth.xy[:, 0], y=truth.xy[:, 1], heading=truth.heading, vx=truth.velocity[:, 0],
                   vy=truth.velocity[:, 1], length=truth.size[:, 0], width=truth.size[:, 1],
                   height=truth.size[:, 2], lane=truth.lane, crashed=truth.crashed,
                   n_points=vis[0], in_range=vis[1])
    m = len(dets.z)
    det_t.append(frame=np.full(m, truth.frame), time=np.full(m, truth.time), x=dets.z[:, 0], y=dets.z[:, 1],
                 provenance=dets.provenance, n_points=dets.n_points, length=dets.extent[:, 0],
                 width=dets.extent[:, 1], height=dets.extent[:, 2])
    t = len(tracks)
    xs, covs = kin  # (t, 2d) [p; v] and (t, 2d, 2d) from the filter's output
    d = xs.shape[1] // 2
    trk_t.append(frame=np.full(t, truth.frame), time=np.full(t, truth.time),
                 track_id=np.array([tr.id for tr in tracks], dtype=np.int64),
                 status=np.asarray(status, dtype=object).reshape(t),
                 x=xs[:, 0], y=xs[:, 1], vx=xs[:, d], vy=xs[:, d + 1],
                 score=np.array([tr.score for tr in tracks], dtype=np.float64),
                 regime=np.array([tr.regime for tr in tracks], dtype=object).reshape(t),
                 cov=covs.reshape(t, covs[0].size if t else 4 * d * d))


def _write_tables(out: Path, tables: dict) -> None:
    for name, log in tables.items():
        write_atomic(out / f"{name}.parquet", log.write)


def write_scores(res: RunResult, tracker_name: str) -> None:
    """``scores.json`` of a run: scenario, seed, tracker, frames, scores, MOT metrics, timings, config."""
    out = res.out_dir
    assert out is not None
    doc = dict(scenario=res.scenario.name, seed=res.scenario.seed, tracker=tracker_name,
               frames=res.n_frames, scores=res.scores.to_dict(), mot_metrics=res.metrics,
               timings_ms_per_frame=res.timings_ms,
               config=to_dict(res.scenario))
    text = json_text(doc, indent=2, default=float) + "\n"  # a score with nothing to measure is null
    write_atomic(out / "scores.json", lambda tmp: tmp.write_text(text, encoding="utf-8"))


def write_outputs(res: RunResult, tracker_name: str) -> None:
    """The tables and scores.json of a finished run into ``res.out_dir``."""
    assert res.out_dir is not None
    _write_tables(res.out_dir, res.tables)
    write_scores(res, tracker_name)
