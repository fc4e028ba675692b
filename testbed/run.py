"""One run of a scenario: traffic -> LiDAR -> ground -> clusters -> detections -> tracker -> scores.

``run_scenario`` is the whole loop; the CLI, the tests and the benchmark call it. Random streams derive
from the scenario seed (``SeedSequence(seed).spawn``), one per consumer, so switching on added clutter
does not change the LiDAR noise.
"""
from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

import sensors
from trackers import make_tracker

from .config import to_dict
from .mot_metrics import mot_metrics
from .roadside import boxes_near, roadside_boxes
from .scenario import Scenario
from .scoring import Scores, score_run
from .simulation import Simulation, lane_polylines, road_edges
from .tables import detections_log, tracks_log, truth_log

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
                 on_frame: Callable[[int, int], None] | None = None) -> RunResult:
    """Run ``scn``; with ``out_dir`` write scores.json, the parquet tables and (``record``) run.rrd."""
    name = tracker_name or scn.tracker.name
    tracker = make_tracker(name, **scn.tracker.params)
    rngs = rng_streams(scn.seed)
    sim = Simulation(scn)
    static = roadside_boxes(road_edges(sim.network), scn.roadside, rngs["roadside"])
    lidar_cfg, perc_cfg, clutter = scn.sensor.lidar, scn.sensor.perception, scn.sensor.clutter
    reach = lidar_cfg.max_range_m + 10.0

    out = Path(out_dir) if out_dir is not None else None
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
    recorder = None
    if out is not None and record:
        from .recording import Recorder  # rerun is imported only when recording

        recorder = Recorder(out / "run.rrd", recording_id=f"{scn.name}-seed{scn.seed}-{name}",
                            lidar_every=scn.record.lidar_every, ground_decimation=scn.record.ground_decimation)
        recorder.static(lane_polylines(sim.network), static)

    truth_t, det_t, trk_t = truth_log(), detections_log(), tracks_log()
    spent = dict.fromkeys(STAGES, 0.0)
    tracks: tuple = ()
    next_id = 1
    seen: set[int] = set()
    n = 0
    tic = time.perf_counter()
    try:
        for truth in sim.frames():
            now = time.perf_counter()
            spent["simulation"] += now - tic
            tic = now

            boxes, ids = truth.boxes()
            near = boxes_near(static, truth.xy[0], reach)
            scene_boxes = np.vstack([boxes, static[near]])
            scene_ids = np.concatenate([ids, np.full(int(near.sum()), -1, dtype=np.int64)])
            scan = sensors.scan(lidar_cfg, truth.ego_pose, scene_boxes, scene_ids, rngs["lidar"])
            now = time.perf_counter(); spent["raycast"] += now - tic; tic = now

            perc = sensors.perceive(scan, perc_cfg)
            dets = perc.detections
            if clutter.density_per_m2 > 0:
                dets = dets.concat(sensors.clutter_detections(rngs["clutter"], clutter.density_per_m2,
                                                              truth.xy[0], clutter.radius_m))
            now = time.perf_counter(); spent["perception"] += now - tic; tic = now

            result = tracker.step(tracks, dets.z, scn.dt if truth.frame > 0 else 0.0, next_id)
            tracks, next_id = result.tracks, result.next_id
            now = time.perf_counter(); spent["tracking"] += now - tic; tic = now

            seen.update(int(p) for p in dets.provenance if p >= 0)
            reported = tuple(t for t in tracks if not t.candidate)  # candidates await a second measurement
            _log_tables(truth, dets, reported, truth_t, det_t, trk_t)
            if recorder is not None:
                recorder.frame(truth, scan, perc, dets, reported, result.info, tracker.params.gate_alpha)
            now = time.perf_counter(); spent["recording"] += now - tic; tic = now
            n += 1
            if on_frame is not None:
                on_frame(n, scn.n_frames)
    except Exception as err:  # keep what was computed: the tables of the frames before the failure
        err.add_note(f"the run stopped at frame {n} (t = {n * scn.dt:.1f} s)")
        if recorder is not None:
            recorder.close()
        if out is not None:
            for name, log in (("truth", truth_t), ("detections", det_t), ("tracks", trk_t)):
                log.write(out / f"{name}.parquet")
        raise

    if recorder is not None:
        t0 = time.perf_counter()
        recorder.close()
        spent["recording"] += time.perf_counter() - t0

    scores, metrics = _score(scn, truth_t, trk_t, np.array(sorted(seen), dtype=np.int64), n)
    timings = {k: 1000.0 * v / max(n, 1) for k, v in spent.items()}
    res = RunResult(scn, scores, timings, n, out, dict(truth=truth_t, detections=det_t, tracks=trk_t), metrics)
    if out is not None:
        write_outputs(res, name)
    return res


def _score(scn: Scenario, truth_t, trk_t, seen: np.ndarray, n_frames: int) -> tuple[Scores, dict[str, float]]:
    """Thesis scores and the standard MOT metrics of a run, from its truth and track tables."""
    keep = ~truth_t.array("is_ego")
    truth = dict(frame=truth_t.array("frame")[keep], vehicle_id=truth_t.array("vehicle_id")[keep],
                 xy=np.column_stack([truth_t.array("x"), truth_t.array("y")])[keep],
                 v=np.column_stack([truth_t.array("vx"), truth_t.array("vy")])[keep])
    tracks = dict(frame=trk_t.array("frame"), track_id=trk_t.array("track_id"),
                  confirmed=trk_t.array("status") == "confirmed",
                  xy=np.column_stack([trk_t.array("x"), trk_t.array("y")]),
                  v=np.column_stack([trk_t.array("vx"), trk_t.array("vy")]))
    sc = scn.scoring
    scores = score_run(truth, tracks, seen, match_distance_m=sc.match_distance_m,
                       correct_fraction=sc.correct_fraction)
    conf = tracks["confirmed"]
    # CLEAR / Identity match within match_distance_m: TrackEval matches at similarity 0.5, and the
    # similarity is 1 - d / (2 match_distance_m) (see testbed/mot_metrics.py).
    metrics = mot_metrics(truth, {k: tracks[k][conf] for k in ("frame", "track_id", "xy")}, n_frames,
                          match_distance_m=2.0 * sc.match_distance_m, gospa_c=sc.match_distance_m)
    return scores, metrics


def _log_tables(truth, dets, tracks, truth_t, det_t, trk_t) -> None:
    k = len(truth.ids)
    truth_t.append(frame=np.full(k, truth.frame), time=np.full(k, truth.time), vehicle_id=truth.ids,
                   name=np.array(truth.names, dtype=object), is_ego=truth.ids == truth.ids[0],
                   x=truth.xy[:, 0], y=truth.xy[:, 1], heading=truth.heading, vx=truth.velocity[:, 0],
                   vy=truth.velocity[:, 1], length=truth.size[:, 0], width=truth.size[:, 1],
                   height=truth.size[:, 2], lane=truth.lane, crashed=truth.crashed)
    m = len(dets.z)
    det_t.append(frame=np.full(m, truth.frame), time=np.full(m, truth.time), x=dets.z[:, 0], y=dets.z[:, 1],
                 provenance=dets.provenance, n_points=dets.n_points, length=dets.extent[:, 0],
                 width=dets.extent[:, 1], height=dets.extent[:, 2])
    t = len(tracks)
    xs = np.array([tr.state.x[:4] for tr in tracks], dtype=np.float64).reshape(t, 4)
    covs = np.array([tr.state.P[:4, :4].reshape(-1) for tr in tracks], dtype=np.float64).reshape(t, 16)
    trk_t.append(frame=np.full(t, truth.frame), time=np.full(t, truth.time),
                 track_id=np.array([tr.id for tr in tracks], dtype=np.int64),
                 status=np.array(["confirmed" if tr.confirmed else "tentative" for tr in tracks], dtype=object),
                 x=xs[:, 0], y=xs[:, 1], vx=xs[:, 2], vy=xs[:, 3],
                 score=np.array([tr.score for tr in tracks], dtype=np.float64), cov=covs)


def write_outputs(res: RunResult, tracker_name: str) -> None:
    out = res.out_dir
    assert out is not None
    for name, log in res.tables.items():
        log.write(out / f"{name}.parquet")
    doc = dict(scenario=res.scenario.name, seed=res.scenario.seed, tracker=tracker_name,
               frames=res.n_frames, scores=res.scores.to_dict(), mot_metrics=res.metrics,
               timings_ms_per_frame=res.timings_ms,
               config=to_dict(res.scenario))
    (out / "scores.json").write_text(json.dumps(doc, indent=2, default=float) + "\n")
