"""``testbed export RUN --format html``: a light 2-D top-down replay of a run, one self-contained HTML file.

The page (template ``replay.html`` beside this module: a canvas, a time slider, play / pause, the event list)
carries the run's data inline as JSON, so it opens from disk in any browser, without a GPU, a server or a
network, in well under a second for a 60 s motorway run (the rerun viewer needs WebGL and, with software
rendering, minutes). It draws, per frame: the lanes, the true vehicle boxes (the sensor car solid vermilion),
the detections (green from a vehicle, red clutter; a further sensor's, e.g. the radar's, blue diamonds), the tentative
tracks (grey), with box tracking each confirmed track's box (dashed), the confirmed tracks in their
viewer colours (testbed/recording/slots.py) with their labels (tags that never overlap), 0.5 s velocity arrows and 2 s trails of fading dots, and a ring
on each event for 3 s (testbed/scoring/events.py). ``replay.html#t=12.5`` or ``#event=3`` opens at a time or
an event.

    write(run, path) -> Path          run: testbed.pipeline.runfolder.RunData
    replay_data(run, lanes) -> dict   the JSON the page reads (schema in the function's docstring)
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd

from ..common.safe_io import refuse_link
from ..recording import palette as pal
from ..recording.slots import track_colours
from ..scoring.events import describe_event
from ..pipeline.outdir import write_atomic

TEMPLATE = Path(__file__).with_name("replay.html")
DATA_MARK = "/*RUN_DATA*/null"
LANE_STEP_M = 5.0  # lane borders are sampled every 5 m, straight stretches kept as their two ends
STATUS = {"confirmed": 0, "tentative": 1, "static": 2}


def write(run, path: str | Path) -> Path:
    """Write the replay of ``run`` (RunData) to ``path`` (atomically; a planted symlink is refused)."""
    out = Path(path)
    refuse_link(out)
    lanes = road_lanes(run.scenario) if run.scenario is not None else []
    data = json.dumps(replay_data(run, lanes), separators=(",", ":"), allow_nan=False)
    page = TEMPLATE.read_text(encoding="utf-8").replace(DATA_MARK, data.replace("</", "<\\/"))
    write_atomic(out, lambda tmp: tmp.write_text(page, encoding="utf-8"))
    return out


def road_lanes(scn) -> list[np.ndarray]:
    """The lane borders of ``scn``'s road, each (P, 2) [m], thinned (:func:`thin_line`): the road is built as the
    run built it (testbed.world), without running the traffic."""
    from ..world.envsource import make_simulation
    from ..world.simulation import lane_polylines

    sim = make_simulation(scn)
    try:
        return [thin_line(ln) for ln in lane_polylines(sim.network, step_m=LANE_STEP_M)]
    finally:
        close = getattr(sim, "close", None)
        if callable(close):
            close()


def thin_line(line: np.ndarray, tol_rad: float = 1e-3) -> np.ndarray:
    """``line`` (P, 2) without the points where it does not turn (by more than ``tol_rad``): a straight lane
    keeps its two ends, a curve every point."""
    if len(line) <= 2:
        return line
    d = np.diff(line, axis=0)
    ang = np.arctan2(d[:, 1], d[:, 0])
    turn = np.abs(np.angle(np.exp(1j * np.diff(ang))))
    keep = np.r_[True, turn > tol_rad, True]
    return line[keep]


def _round(a, nd: int = 2) -> list:
    """Floats rounded to ``nd`` decimals, NaN as None (JSON null)."""
    v = np.round(np.asarray(a, dtype=np.float64), nd)
    out = v.tolist()
    if not np.isfinite(v).all():
        out = [x if np.isfinite(x) else None for x in out]
    return out


def _per_frame(df: pd.DataFrame, n_frames: int, cols: dict[str, tuple[str, int]]) -> dict:
    """Rows of ``df`` (with ``frame``) sorted by frame, as columns plus ``start`` (F+1,): frame f's rows are
    start[f]:start[f+1]. cols: {json key: (column, decimals; -1 for integers)}."""
    df = df.sort_values("frame", kind="stable")
    frame = df["frame"].to_numpy(dtype=np.int64)
    out = {"start": np.searchsorted(frame, np.arange(n_frames + 1)).tolist()}
    for key, (col, nd) in cols.items():
        out[key] = df[col].to_numpy(dtype=np.int64).tolist() if nd < 0 else _round(df[col], nd)
    return out


def _hex(rgb) -> str:
    return "#" + "".join(f"{int(c):02x}" for c in list(rgb)[:3])


def replay_data(run, lanes: list[np.ndarray]) -> dict:
    """The page's data: ``meta`` (scenario, tracker, seed, rate_hz, frames), ``time`` (F,) [s], ``lanes``
    (flat [x0, y0, x1, y1, ...] per border line) [m], ``truth`` (per frame: id, x, y [m], h [rad], l, w [m],
    ego 0/1), ``dets`` (x, y, c: 1 clutter), ``tracks`` (id, x, y, vx, vy [m/s], s: 0 confirmed, 1 tentative,
    2 static; with box tracking h [rad], l, w [m]), ``sensors`` (x, y: the further sensors' detections), per-frame columns with ``start`` (F+1,) (frame f's rows: start[f]:start[f+1]); ``colours``
    {track id: "#rrggbb"} (the viewer's); ``events`` [{n, frame, time, kind, cause, text, car, track}];
    ``style``: the scene's colours."""
    truth, tracks, dets = run.truth, run.tracks, run.detections
    n = run.n_frames
    times = truth.groupby("frame")["time"].first().reindex(range(n))
    time = np.where(np.isfinite(times.to_numpy(dtype=np.float64)), times.to_numpy(dtype=np.float64),
                    np.arange(n) / (run.scenario.rate_hz if run.scenario is not None else 10.0))
    scn = run.scenario
    meta = dict(scenario=str(run.scores.get("scenario", run.folder.name)), tracker=str(run.scores.get("tracker", "?")),
                seed=run.scores.get("seed"), rate_hz=float(scn.rate_hz) if scn is not None else 10.0, frames=n,
                incomplete=run.incomplete)
    tr = truth.assign(ego=truth["is_ego"].astype(np.int64)) if "is_ego" in truth.columns else truth.assign(ego=0)
    tk = tracks.assign(s=tracks["status"].astype(str).map(STATUS).fillna(1).astype(np.int64))
    dt = dets.assign(c=(dets["provenance"].to_numpy() < 0).astype(np.int64))
    events = []
    if run.events is not None:
        for r in run.events.to_dict("records"):
            track = int(r["new_track"]) if r["kind"] == "false track" else -1
            events.append(dict(n=int(r["event"]), frame=int(r["frame"]), time=round(float(r["time"]), 3),
                               kind=str(r["kind"]), cause=str(r["cause"]), text=describe_event(r),
                               car=int(r["car"]), track=track))
    box = {k: (c, 3 if k == "h" else 2) for k, c in (("h", "heading"), ("l", "length"), ("w", "width"))
           if {"heading", "length", "width"} <= set(tracks.columns)}  # box tracking: the tracks' boxes
    sensors = pd.concat([d[["frame", "x", "y"]] for d in run.sensors.values()]) if run.sensors else \
        pd.DataFrame({"frame": np.zeros(0, np.int64), "x": np.zeros(0), "y": np.zeros(0)})
    return dict(
        meta=meta, time=_round(time, 3),
        lanes=[_round(np.asarray(ln).reshape(-1), 2) for ln in lanes],
        truth=_per_frame(tr, n, dict(id=("vehicle_id", -1), x=("x", 2), y=("y", 2), h=("heading", 3),
                                     l=("length", 2), w=("width", 2), ego=("ego", -1))),
        dets=_per_frame(dt, n, dict(x=("x", 2), y=("y", 2), c=("c", -1))),
        tracks=_per_frame(tk, n, dict(id=("track_id", -1), x=("x", 2), y=("y", 2), vx=("vx", 2), vy=("vy", 2),
                                      s=("s", -1), **box)),
        sensors=_per_frame(sensors, n, dict(x=("x", 2), y=("y", 2))),
        colours={str(t): _hex(c) for t, c in track_colours(tracks).items()},
        events=events,
        style=dict(ego=_hex(pal.EGO), detection=_hex(pal.DETECTION), clutter=_hex(pal.CLUTTER), sensor=_hex(pal.SENSOR),
                   tentative=_hex(pal.UNSLOTTED), event=_hex(pal.EVENT)),
    )
