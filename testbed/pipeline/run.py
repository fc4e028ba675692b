"""One run of a scenario: sensing (testbed.sensing) -> any tracker (testbed.tracking) -> tables, scores, recording.

``run_scenario`` is the whole loop; the CLI, the campaigns, the tests and the benchmarks call it.
"""
from __future__ import annotations

import errno
import os
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterable, Iterator

import numpy as np
import pandas as pd

from roadtrack import sensors

from ..config import ConfigError, to_dict
from ..common.jsonio import json_text
from ..tracking.moving import MovingTest
from .outdir import write_atomic
from ..scenario.spec import Scenario
from ..scoring.events import run_events
from ..scoring.rates import Scores
from ..sensing import (SensedFrame, SensingContext, rng_streams, scenario_sensors, sense_simulation, sensing_setup,
                       sensor_registry)
from ..common.errors import interruption_behind
from ..sensing.cache import SensingCache
from ..world.simulation import lane_polylines
from .tables import diagnostics_log, detections_log, sensor_detections_log, tracks_log, truth_log
from ..tracking import Frame, TrackSet, build_tracker, tracker_label

STAGES = ("simulation", "raycast", "perception", "tracking", "recording")


@dataclass
class RunResult:
    scenario: Scenario
    scores: Scores
    timings_ms: dict[str, float]          # mean ms per frame per stage
    n_frames: int
    out_dir: Path | None
    tables: dict = field(default_factory=dict)  # name -> TableLog
    metrics: dict[str, float] = field(default_factory=dict)  # standard MOT metrics (HOTA, MOTA, IDF1, GOSPA)
    tracker: str = ""  # the tracker's name in the outputs
    fallbacks: int = 0  # association problems solved by a fallback over the run (TrackSet.fallbacks summed)
    events: pd.DataFrame | None = None  # relabels, false tracks, missed cars (testbed.scoring.events.run_events)
    stitched: int = 0  # tracks given a deleted track's label over the run (TrackSet.stitched summed)

    def summary(self) -> dict[str, float]:
        """Flat dict of every scalar score of the run: thesis scores, MOT metrics, ms per frame per stage."""
        out = dict(self.scores.to_dict())
        out.update(self.metrics)
        out.update({f"ms_{k}": v for k, v in self.timings_ms.items()})
        return out


def _events(scn: Scenario, tables: dict):
    """(events, truth, tracks): the run's events (testbed.scoring.events.run_events) and the two frames they were
    computed from (the recording marks them); a campaign's runs without a folder skip this."""
    truth_df, tracks_df = event_frames(tables["truth"], tables["tracks"])
    return run_events(truth_df, tracks_df, scn.scoring, scn.dt), truth_df, tracks_df


def _timed(fn: Callable[[], object], watch: Stopwatch, stage: str) -> None:
    """fn() with its wall time added to ``watch``'s ``stage``."""
    t0 = time.perf_counter()
    fn()
    watch.spent[stage] += time.perf_counter() - t0


def _open_outputs(scn: Scenario, out: Path | None, record: bool, name: str, setup, source):
    """The run folder created (when there is one) and the recorder writing run.rrd into it, or None."""
    if out is None:
        return None
    out.mkdir(parents=True, exist_ok=True)
    if not record:
        return None
    lanes, static = source.scene() if source is not None else (lane_polylines(setup()[0].network), setup()[1])
    return _recorder(scn, out / "run.rrd", name, lanes, static)


def run_scenario(scn: Scenario, out_dir: str | Path | None = None, record: bool = True, tracker=None,
                 on_frame: Callable[[int, int], None] | None = None, policy: Callable | None = None,
                 label: str | None = None, sensing_cache: str | Path | None = None, source=None) -> RunResult:
    """Run ``scn``; with ``out_dir`` write scores.json, the parquet tables and (``record``) run.rrd, each file
    atomically (complete or absent).

    ``tracker``: None (the scenario's), a built-in name (``jpda-kf``), ``module:Name`` / ``file.py:Name``, a
    factory of the scenario, or a tracker object (testbed.tracking: anything with ``step(frame) -> TrackSet``).
    On any exception, Ctrl-C included, the recording is closed and the tables of the frames done are written
    before it propagates, with a note saying where the run stopped. JPDA overflow warnings (one per oversize
    cluster) are counted and given once at the end of the run. ``policy``: the ego's policy
    ``f(observation, info) -> action`` for a scenario with ``[env]`` (testbed/world/envsource.py), replacing the
    file's built-in one. ``label``: the tracker's name in the outputs (default: its built-in name, the
    ``module:Name`` given, or the class's name). ``sensing_cache``: a folder (testbed.sensing.cache) the sensed
    frames are read from when there, else stored in; not with a ``policy`` (a user's code is not part of the key).
    Frames from the cache carry no point cloud: the recording then shows no LiDAR points. ``source``: the frames
    come from elsewhere instead of the scenario's traffic (a replayed recording, testbed.pipeline.replay): an
    object with ``scene() -> (lanes, static)`` (the lane borders and roadside boxes the recording draws) and
    ``frames(watch) -> iterator of SensedFrame``."""
    name = label or tracker_label(tracker, scn)
    trk = build_tracker(scn, tracker)  # before the traffic is set up: a bad tracker fails at once
    scenario_sensors(scn)  # so does an unknown sensor of sensor.extra
    rngs = rng_streams(scn.seed)
    setup = _Setup(scn, rngs, policy)  # the traffic is set up when needed: not for a run read from the cache
    cache = SensingCache(sensing_cache) if sensing_cache is not None and policy is None and source is None else None
    if source is None and (cache is None or (record and out_dir is not None) or not cache.has(scn)):
        setup()  # before any output: a traffic that cannot be set up fails with nothing written
    out = Path(out_dir) if out_dir is not None else None
    recorder = _open_outputs(scn, out, record, name, setup, source)
    tables = run_tables(scn)
    watch = Stopwatch()
    state = _Progress()
    overflows = JPDAOverflows()
    closing = None  # the recorder once closed
    try:
        if source is not None:
            frames = source.frames(watch)
        else:
            frames = cache.frames(scn, setup, watch) if cache is not None else sense_simulation(scn, *setup(), rngs,
                                                                                                   watch)
        _frames(scn, trk, frames, recorder, tables, watch, state, overflows, on_frame)
        state.looping = False
        events, truth_df, tracks_df = _events(scn, tables) if out is not None or recorder is not None else (None,) * 3
        if recorder is not None:
            recorder.events(events, truth_df, tracks_df)  # marked in the recording before it is closed
            closing, recorder = recorder, None  # closed once, even if closing fails
            _timed(lambda: _close_recording(closing), watch, "recording")  # its compaction started in its own process
        scores, metrics = score_tables(scn, tables["truth"], tables["tracks"], state.frames)
        if closing is not None:  # the compaction ran beside the scoring: the wait left is the recording's
            _timed(closing.wait_compacted, watch, "recording")
        timings = {k: 1000.0 * v / max(state.frames, 1) for k, v in watch.spent.items()}
        res = RunResult(scn, scores, timings, state.frames, out, tables, metrics, name, state.fallbacks, events,
                        state.stitched)
        if out is not None:
            _write_tables(out, tables)
            write_atomic(out / EVENTS_FILE, lambda tmp: events.to_parquet(tmp, index=False))
            state.tables_written = True
            write_scores(res, name)
    except BaseException as err:  # keep what was computed: the tables of the frames before the failure
        stop = interruption_behind(err)
        _keep_partial(stop, scn, state, recorder, out, tables)
        if stop is not err:
            raise stop from None
        raise
    finally:
        if closing is not None:
            closing.cancel_compaction()  # after a failure: stopped, the recording kept as written
        overflows.report()
    return res


class _Setup:
    """``sensing_setup`` of a run, done once on the first call: () -> (sim, static, road)."""

    def __init__(self, scn: Scenario, rngs: dict, policy: Callable | None):
        self.args, self.done = (scn, rngs, policy), None

    def __call__(self):
        if self.done is None:
            self.done = sensing_setup(*self.args)
        return self.done


@dataclass
class _Progress:
    """Where a run is: frames done, whether still in the frame loop, whether its tables are written."""

    frames: int = 0
    looping: bool = True
    tables_written: bool = False
    rows: dict[str, int] = field(default_factory=dict)  # each table's rows at the end of the last frame done
    fallbacks: int = 0  # TrackSet.fallbacks summed over the frames done
    stitched: int = 0  # TrackSet.stitched summed over the frames done


def run_tables(scn: Scenario) -> dict:
    """The empty tables of a run of ``scn`` by file stem (README, "Output files"): truth, detections, tracks (with
    box columns under box tracking), diagnostics and each further sensor's ``detections-<name>``."""
    return dict(truth=truth_log(), detections=detections_log(), tracks=tracks_log(scn.tracker.box),
                diagnostics=diagnostics_log(),
                **{f"detections-{sensor}": sensor_detections_log() for sensor in further_tables(scn)})


def further_tables(scn: Scenario) -> list[str]:
    """The further sensors (sensor.extra) whose detections a run writes to ``detections-<name>.parquet``: those with
    a ``measurements`` hook (their detections carry a measurement model, so a position to show)."""
    return [s.name for s in scenario_sensors(scn)[1:] if s.measurements is not None]


def further_measurements(sensed: SensedFrame, ctx: SensingContext) -> dict:
    """The further sensors' detections of ``sensed`` with their measurement models (testbed.sensing.Measurements,
    by sensor name; sensors without a ``measurements`` hook are left out)."""
    meas = {}
    if sensed.others:
        known = sensor_registry()
        for name, reading in sensed.others.items():
            hook = known[name].measurements if name in known else None
            if hook is not None:
                meas[name] = hook(ctx, sensed.truth, reading.data)
    return meas


def tracker_frame(sensed: SensedFrame, dt: float, ctx: SensingContext | None = None) -> Frame:
    """What a tracker is fed of a sensed frame (testbed.tracking.Frame): the detections without their truth, and
    (given the run's ``ctx``) the further sensors' measurements (their ``measurements`` hook)."""
    d = sensed.detections
    meas = further_measurements(sensed, ctx) if ctx is not None else {}
    return Frame(index=sensed.index, time=sensed.time, dt=dt, z=d.z, R=d.R, extent=d.extent, heading=d.heading,
                 pd=sensed.pd, road=sensed.road.lane_frame if sensed.road is not None else None, measurements=meas)


def track(frames: Iterable[SensedFrame], tracker, scn: Scenario,
          overflows: "JPDAOverflows | None" = None) -> Iterator[tuple[SensedFrame, TrackSet]]:
    """The one tracking loop: each sensed frame fed to ``tracker`` (anything :func:`run_scenario` takes, built
    once by testbed.tracking.build_tracker), yielding the frame and the tracker's TrackSet with the moving-object
    test's status ("confirmed", "tentative", "static"). ``overflows``: JPDA overflow warnings counted there
    instead of shown one by one. The tracker is built and ``frames`` checked at the call (an unknown tracker or
    frames that are not iterable fail there, in one line), the frames are tracked as the iterator is read."""
    return (pair for pair, _ in _track(frames, tracker, scn, overflows))


def _track(frames: Iterable[SensedFrame], tracker, scn: Scenario,
           overflows: "JPDAOverflows | None" = None) -> Iterator[tuple[tuple[SensedFrame, TrackSet], Frame]]:
    """:func:`track`, each (sensed frame, TrackSet) with the tracker's Frame (its further sensors' measurements are
    logged from it, not made twice)."""
    trk = build_tracker(scn, tracker)
    try:
        frames = iter(frames)
    except TypeError:
        raise ConfigError("frames", f"expected the frames testbed.sense yields, got a {type(frames).__name__}, "
                          f"which is not iterable") from None
    return _tracked(frames, trk, scn, overflows)


def _tracked(frames: Iterator, trk, scn: Scenario, overflows) -> Iterator[tuple[tuple[SensedFrame, TrackSet], Frame]]:
    moving = MovingTest(scn.moving_test)
    ctx = SensingContext(scn, None, None)  # what the further sensors' measurements hooks read
    for k, sensed in enumerate(frames):
        if not isinstance(sensed, SensedFrame):
            raise ConfigError("frames", f"item {k} is a {type(sensed).__name__}, not a testbed.sensing.SensedFrame "
                              f"(what testbed.sense yields)")
        frame = tracker_frame(sensed, scn.dt if sensed.index > 0 else 0.0, ctx)
        ts = overflows.call(trk.step, frame) if overflows is not None else trk.step(frame)
        if not isinstance(ts, TrackSet):
            from ..common.errors import RunError

            raise RunError(f"the tracker's step returned a {type(ts).__name__}, not a testbed.tracking.TrackSet")
        yield (sensed, ts.with_status(track_status(ts, moving, sensed.time))), frame


def _frames(scn, tracker, frames, recorder, tables, watch, state: _Progress, overflows, on_frame) -> None:
    """The frame loop: track each sensed frame, log, record; ``state.frames`` counts the frames done."""
    for (sensed, ts), frame in _track(frames, tracker, scn, overflows):
        truth = sensed.truth
        watch.lap("tracking")
        log_tables(truth, sensed.visibility, sensed.detections, ts, tables["truth"], tables["detections"],
                   tables["tracks"])
        log_diagnostics(truth, ts, tables["diagnostics"])
        others = log_sensor_detections(truth, frame.measurements, tables)
        if recorder is not None:
            live = sensed.perception is not None  # a cached frame has no point cloud to show
            recorder.frame(truth, sensed.scan if live else None, sensed.perception, sensed.detections, ts, others)
        watch.lap("recording")
        state.rows = {k: log.n_rows for k, log in tables.items()}
        state.fallbacks += ts.fallbacks
        state.stitched += ts.stitched
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
    from ..common.errors import one_line

    if isinstance(err, OSError) and err.errno:
        return os.strerror(err.errno).lower()
    return f"{type(err).__name__}: {one_line(err)}"


LOW_SPACE_BYTES = 1 << 20
"""Free space below which a recording that rerun could not finish is reported as a full disk."""


def _close_recording(recorder) -> None:
    """Close the recording, within a bound (:data:`testbed.recording.recorder.CLOSE_STALL_S` without progress). rerun's
    file writer stopping early (it has logged why; ours is then the last line) or rerun not finishing is raised
    as an OSError ENOSPC naming the file when its disk is (nearly) full, else as a RunError."""
    from ..common.errors import RunError, one_line

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


class JPDAOverflows:
    """JPDA overflow warnings of a run (one per oversize cluster and frame), given once at the end with a
    count; other warnings of the tracker pass through (each once per run)."""

    def __init__(self):
        self.frames = 0
        self.clusters = 0
        self.largest = (0, 0)  # (tracks, measurements) of the largest cluster (by tracks x measurements)
        self.registry: dict = {}

    def call(self, func, *args, **kwargs):
        from roadtrack.trackers import JPDAOverflowWarning

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
        from roadtrack.trackers import JPDAOverflowWarning

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


_STATUS_LABELS = np.array(["tentative", "static", "confirmed"], dtype=object)


def track_status(ts: TrackSet, moving: MovingTest, time: float) -> np.ndarray:
    """(T,) object array: "confirmed" (reported), "tentative", or "static" (confirmed by the tracker but
    not yet seen to move, testbed/tracking/moving.py: tracked, not reported, not scored)."""
    moved = moving.update(ts.ids, ts.xy, time)
    conf = ts.status == "confirmed"
    # three shared str objects, not one new str per row (a long run keeps every frame's rows in memory)
    return _STATUS_LABELS[np.where(conf, np.where(moved, 2, 1), 0)]


def _recorder(scn: Scenario, path: Path, tracker_name: str, lanes: list, static: np.ndarray):
    """A :class:`~testbed.recording.recorder.Recorder` with the road and roadside objects logged."""
    from ..recording.levels import lidar_step
    from ..recording.recorder import FOOTER_MAX_FRAMES, Recorder  # rerun is imported only when recording

    rec = Recorder(path, recording_id=f"{scn.name}-seed{scn.seed}-{tracker_name}",
                   lidar_every=lidar_step(scn.record.lidar_every, scn.record.max_lidar_frames, scn.n_frames),
                   ground_decimation=scn.record.ground_decimation,
                   write_footer=scn.n_frames <= FOOTER_MAX_FRAMES,
                   occlusion=sensors.OcclusionConfig.from_lidar(scn.sensor.lidar), max_range_m=scn.sensor.lidar.max_range_m,
                   level=scn.record.level, rate_hz=scn.rate_hz, compact=True)
    rec.static(lanes, static)
    return rec


EVENTS_FILE = "events.parquet"


def event_frames(truth_t, trk_t) -> tuple[pd.DataFrame, pd.DataFrame]:
    """The truth and tracks columns the events need (testbed.scoring.events.run_events), as DataFrames, from a
    run's tables (testbed.pipeline.tables TableLog)."""
    cols = ("frame", "vehicle_id", "x", "y", "vx", "vy", "n_points", "is_ego", "heading")
    truth = pd.DataFrame({c: truth_t.array(c) for c in cols})
    tracks = pd.DataFrame({c: trk_t.array(c) for c in ("frame", "track_id", "x", "y", "vx", "vy", "status")})
    return truth, tracks


def score_tables(scn: Scenario, truth_t, trk_t, n_frames: int) -> tuple[Scores, dict[str, float]]:
    """Thesis scores and the MOT metrics (visible truth, and all truth as ``*_all``) of a run's tables
    (testbed.pipeline.tables TableLog): testbed.scoring.evaluate.score on them."""
    from ..scoring.evaluate import score

    cols = ("frame", "vehicle_id", "x", "y", "vx", "vy", "n_points", "is_ego")
    box = ("heading", "length", "width") if "heading" in trk_t.columns else ()  # box tracking: its scores too
    truth = pd.DataFrame({c: truth_t.array(c) for c in cols + box})
    tracks = pd.DataFrame({c: trk_t.array(c) for c in ("frame", "track_id", "x", "y", "vx", "vy", "status") + box})
    ev = score(truth, tracks, scn.scoring, n_frames)
    return ev.scores, ev.metrics


def log_diagnostics(truth, ts: TrackSet, diag_t) -> None:
    """Long format: one row per (track, quantity) of the step's diagnostics (NIS, gate volume, the filters'
    boundary layers and mode probabilities, the associator's extras; a user tracker's own)."""
    ids = ts.diagnostic_ids
    if not len(ids) or not ts.diagnostics:
        return
    names = sorted(ts.diagnostics)
    values = np.stack([ts.diagnostics[k] for k in names], axis=1)  # (K, N)
    keep = np.isfinite(values)
    rows, cols = np.nonzero(keep)
    diag_t.append(frame=np.full(rows.size, truth.frame), time=np.full(rows.size, truth.time),
                  track_id=ids[rows], name=np.array(names, dtype=object)[cols], value=values[rows, cols])


def log_tables(truth, vis, dets, ts: TrackSet, truth_t, det_t, trk_t) -> None:
    """One frame's rows of the truth, detections and tracks tables (README, "Output files")."""
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
                 width=dets.extent[:, 1], height=dets.extent[:, 2], r_xx=dets.R[:, 0, 0], r_xy=dets.R[:, 0, 1],
                 r_yy=dets.R[:, 1, 1])
    t = len(ts)
    box = {}
    if "heading" in trk_t.columns:  # box tracking (tracker.box)
        b = ts.box if ts.box is not None else np.full((t, 3), np.nan)
        box = dict(heading=b[:, 0], length=b[:, 1], width=b[:, 2])
    trk_t.append(frame=np.full(t, truth.frame), time=np.full(t, truth.time), track_id=ts.ids, status=ts.status,
                 x=ts.xy[:, 0], y=ts.xy[:, 1], vx=ts.v[:, 0], vy=ts.v[:, 1], score=ts.score, regime=ts.regime,
                 cov=ts.cov.reshape(t, 16), **box)


def log_sensor_detections(truth, meas: dict, tables: dict) -> dict[str, np.ndarray]:
    """One frame's rows of each further sensor's table (``detections-<name>``) from its measurements ``meas``;
    returns the positions they imply by sensor name (M, 2) [m] for the recording."""
    out = {}
    for name, m in meas.items():
        log = tables.get(f"detections-{name}")
        if log is None:
            continue
        n = len(m.z)
        xy = np.array([m.model.position_of(z)[0][:2] for z in m.z], dtype=np.float64).reshape(n, 2)
        log.append(frame=np.full(n, truth.frame), time=np.full(n, truth.time), x=xy[:, 0], y=xy[:, 1], z=m.z)
        out[name] = xy
    return out


def _write_tables(out: Path, tables: dict) -> None:
    for name, log in tables.items():
        write_atomic(out / f"{name}.parquet", log.write)


def write_scores(res: RunResult, tracker_name: str) -> None:
    """``scores.json`` of a run: scenario, seed, tracker, frames, association fallbacks (TrackSet.fallbacks summed:
    association problems over their exact budget, solved by a fallback), stitched tracks (TrackSet.stitched summed:
    tracks given a recently deleted track's label, tracker.stitch_s; the scores count them as that track), scores,
    MOT metrics, timings, config."""
    out = res.out_dir
    assert out is not None
    doc = dict(scenario=res.scenario.name, seed=res.scenario.seed, tracker=tracker_name,
               frames=res.n_frames, association_fallbacks=res.fallbacks, stitched_tracks=res.stitched,
               scores=res.scores.to_dict(), mot_metrics=res.metrics,
               timings_ms_per_frame=res.timings_ms,
               config=to_dict(res.scenario))
    text = json_text(doc, indent=2, default=float) + "\n"  # a score with nothing to measure is null
    write_atomic(out / "scores.json", lambda tmp: tmp.write_text(text, encoding="utf-8"))
