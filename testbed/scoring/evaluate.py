"""Scores from plain tables: ``score(truth, tracks)`` gives the thesis scores (TP / FP / break-up %, RMSE; testbed/
scoring.py) and the MOT metrics (HOTA, MOTA, IDF1, GOSPA; testbed/scoring/mot_metrics.py) of any tracks table against a
run's truth, so a tracker written in any language can be scored (``testbed score RUN --tracks FILE``).

Tables are pandas DataFrames or pyarrow Tables (or anything ``pandas.DataFrame(...)`` takes).

truth (README, "Output files", truth.parquet): frame, vehicle_id, x, y [m], vx, vy [m/s], n_points (LiDAR points on
    the vehicle that frame), optionally is_ego (those rows are dropped).
tracks: frame (or time [s], matched to the truth's frame times within half a frame), track_id (or id), x, y [m];
    optionally vx, vy [m/s] (else NaN: no velocity RMSE) and status ("confirmed" rows are scored; without the
    column every row is confirmed).
With box columns heading [rad], length, width [m] in both tables (box tracking, ``tracker.box``), the metrics also
hold the box-overlap ones as ``bev_*`` (bird's-eye-view IoU as the similarity, testbed/scoring/boxes.py; visible
truth).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from ..config import ConfigError
from .boxes import box_metrics
from .mot_metrics import mot_metrics, visible_truth
from ..scenario.spec import ScoringSpec
from .rates import Scores, score_run


@dataclass(frozen=True)
class Evaluation:
    """The scores of one tracks table: ``scores`` (thesis form and ours, testbed.scoring.rates.Scores) and ``metrics``
    (MOT metrics of the visible truth, and of all truth as ``*_all``)."""

    scores: Scores
    metrics: dict[str, float] = field(default_factory=dict)

    def summary(self) -> dict[str, float]:
        return {**self.scores.to_dict(), **self.metrics}


def _frame(table, what: str) -> pd.DataFrame:
    if isinstance(table, pd.DataFrame):
        return table
    if hasattr(table, "to_pandas"):
        return table.to_pandas()
    try:
        return pd.DataFrame(table)
    except (TypeError, ValueError) as err:
        raise ConfigError(what, f"expected a table (pandas or pyarrow), got {type(table).__name__}") from err


def _column(df: pd.DataFrame, what: str, *names: str) -> str:
    for name in names:
        if name in df.columns:
            return name
    raise ConfigError(what, f"no column {' or '.join(map(repr, names))} (columns: {', '.join(map(str, df.columns))})")


def _numbers(df: pd.DataFrame, col: str, what: str) -> np.ndarray:
    try:
        a = df[col].to_numpy(dtype=np.float64)
    except (TypeError, ValueError):
        raise ConfigError(f"{what}.{col}", "expected numbers") from None
    return a


def score(truth, tracks, scoring: ScoringSpec | None = None, n_frames: int | None = None) -> Evaluation:
    """Score ``tracks`` against ``truth`` (schemas in the module docstring) with ``scoring`` (default: the
    scenario defaults, testbed.scenario.spec.ScoringSpec). ``n_frames``: frames of the run (default: the truth's).
    ConfigError (one line, naming the table and column) on a missing column, a non-numeric or non-finite
    position, or a track time that matches no frame."""
    sc = scoring or ScoringSpec()
    truth_rows, track_rows = scoring_rows(truth, tracks, sc)
    conf = track_rows["confirmed"]
    g_frame = truth_rows["frame"]
    n = int(n_frames) if n_frames is not None else (int(g_frame.max()) + 1 if len(g_frame) else 0)
    scores = score_run(truth_rows, track_rows, match_distance_m=sc.match_distance_m,
                       correct_fraction=sc.correct_fraction)
    scale = sc.similarity_scale_m or sc.match_distance_m
    g_all = {k: truth_rows[k] for k in ("frame", "vehicle_id", "xy", "visible")}
    t_all = {k: track_rows[k][conf] for k in ("frame", "track_id", "xy")}
    g_vis, t_vis = visible_truth(g_all, t_all, scale)
    kw = dict(similarity_scale_m=scale, gospa_c=sc.match_distance_m)
    metrics = mot_metrics(g_vis, t_vis, n, **kw)
    metrics.update({f"{k}_all": val for k, val in mot_metrics(g_all, t_all, n, **kw).items()})
    if "box" in truth_rows and "box" in track_rows:  # box tracking: the box-overlap scores beside
        g_box = {**g_all, "box": truth_rows["box"]}
        g_vis_b, t_vis_b = visible_truth(g_box, {**t_all, "box": track_rows["box"][conf]}, scale)
        metrics.update({f"bev_{k}": val for k, val in box_metrics(g_vis_b, t_vis_b, n).items()})
    return Evaluation(scores, metrics)


def _boxes(df: pd.DataFrame, what: str) -> np.ndarray | None:
    """Boxes (N, 5) [x, y, heading, length, width] of a table with heading, length, width columns, else None."""
    if not {"heading", "length", "width"} <= set(df.columns):
        return None
    return np.column_stack([_numbers(df, c, what) for c in ("x", "y", "heading", "length", "width")])


def scoring_rows(truth, tracks, sc: ScoringSpec) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """The truth and tracks tables (schemas in the module docstring) checked and as the arrays
    testbed.scoring.rates.score_run takes: truth frame, vehicle_id (N,), xy, v (N, 2), visible (N,) bool (at least
    ``sc.visible_min_points`` points; the ego's rows dropped); tracks frame, track_id (Q,), confirmed (Q,) bool,
    xy, v (Q, 2). ConfigError as :func:`score`."""
    g = _frame(truth, "truth")
    t = _frame(tracks, "tracks")
    for col in ("frame", "vehicle_id", "x", "y", "vx", "vy", "n_points"):
        _column(g, "truth", col)
    if "is_ego" in g.columns:
        g = g[~g["is_ego"].to_numpy(dtype=bool)]
    g_frame = g["frame"].to_numpy(dtype=np.int64)
    truth_rows = dict(frame=g_frame, vehicle_id=g["vehicle_id"].to_numpy(dtype=np.int64),
                      xy=np.column_stack([_numbers(g, "x", "truth"), _numbers(g, "y", "truth")]),
                      v=np.column_stack([_numbers(g, "vx", "truth"), _numbers(g, "vy", "truth")]),
                      visible=g["n_points"].to_numpy(dtype=np.int64) >= sc.visible_min_points)
    if (g_box := _boxes(g, "truth")) is not None:
        truth_rows["box"] = g_box
    frame = _track_frames(t, g, _column(t, "tracks", "frame", "time"))
    tid = _column(t, "tracks", "track_id", "id")
    try:
        ids = t[tid].to_numpy(dtype=np.int64)
    except (TypeError, ValueError):
        raise ConfigError(f"tracks.{tid}", "expected integer labels") from None
    xy = np.column_stack([_numbers(t, _column(t, "tracks", "x"), "tracks"), _numbers(t, _column(t, "tracks", "y"), "tracks")])
    bad = ~np.isfinite(xy).all(axis=1)
    if bad.any():
        raise ConfigError("tracks.x, tracks.y", f"{int(bad.sum())} rows hold a non-finite position (first: row "
                          f"{int(np.flatnonzero(bad)[0])})")
    v = np.column_stack([_numbers(t, c, "tracks") if c in t.columns else np.full(len(t), np.nan) for c in ("vx", "vy")])
    conf = (t["status"].astype(str).to_numpy() == "confirmed") if "status" in t.columns else np.ones(len(t), bool)
    track_rows = dict(frame=frame, track_id=ids, confirmed=conf, xy=xy, v=v)
    if (t_box := _boxes(t, "tracks")) is not None:
        track_rows["box"] = t_box
    return truth_rows, track_rows


def _track_frames(t: pd.DataFrame, g: pd.DataFrame, col: str) -> np.ndarray:
    """The frame number of each track row: its ``frame``, or its ``time`` matched to the truth's frame times."""
    if col == "frame":
        try:
            return t["frame"].to_numpy(dtype=np.int64)
        except (TypeError, ValueError):
            raise ConfigError("tracks.frame", "expected integer frame numbers") from None
    if "time" not in g.columns:
        raise ConfigError("truth", "the tracks table has times but the truth no 'time' column")
    times = g.groupby("frame")["time"].first()
    ft, fn = times.to_numpy(dtype=np.float64), times.index.to_numpy(dtype=np.int64)
    tt = _numbers(t, "time", "tracks")
    if not len(ft):
        return np.zeros(len(tt), np.int64)
    half = 0.5 * float(np.min(np.diff(ft))) if len(ft) > 1 else 0.5
    at = np.clip(np.searchsorted(ft, tt), 1, len(ft) - 1) if len(ft) > 1 else np.zeros(len(tt), np.int64)
    if len(ft) > 1:
        at = np.where(np.abs(ft[at - 1] - tt) <= np.abs(ft[at] - tt), at - 1, at)
    off = ~(np.abs(ft[at] - tt) <= half + 1e-9)
    if off.any():
        raise ConfigError("tracks.time", f"{int(off.sum())} rows at times no frame of the run has (first: "
                          f"{tt[np.flatnonzero(off)[0]]!r} s)")
    return fn[at]
