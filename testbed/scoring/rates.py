"""Thesis scores per car (TP / FP / track break-ups, thesis Tables 4.3 and 5.4), RMSE, coverage.

The thesis (Attari, "SVSF for tracking with data association", §4.6.2 and §5.6.2) defines the scores
in words only: TP "is an indicator of the number of correctly tracked targets", FP "an indicator of
the number of falsely tracked objects", and the break-up rate "counts the number of re-labeled
targets". Its Table 4.3 gives "# of Cars 58", 49 correctly and 9 falsely tracked, TP 84.48 % = 49/58,
FP 15.52 % = 9/58: the denominator is the number of cars, not of tracks. Where it is silent (the match
distance, what "correctly tracked" means, which cars count) we choose, and say so:

1. **Cars seen**: vehicles (ego excluded) hit by at least one LiDAR beam in at least one frame
   (truth column ``visible``). The denominator of every thesis-form percentage.
2. **Assignment** (ours): every frame, confirmed tracks are assigned one to one to the true vehicles
   of that frame (visible or not: a track coasting through an occlusion is still on its car) by
   minimum total position distance (Hungarian), a pair being allowed only within
   ``match_distance_m``.
3. **Correct track** (ours): a confirmed track assigned to one and the same vehicle for at least
   ``correct_fraction`` of the frames of its confirmed life; that vehicle is its car. Any other
   confirmed track is a **false track** (clutter, a static object, a duplicate, a track that flips
   between cars).
4. **Car correctly tracked**: a car seen that is the car of at least one correct track.
5. **Car relabelled**: a car seen whose sequence of assigned confirmed track labels changes at least
   once (thesis: "a previously confirmed target missed over a number of frames ... treated as a new
   track, with a new label"). Every change is a **relabel event**.

Thesis-table form (the CLI table and the campaign reports use these):

    TP %       = 100 x cars correctly tracked / cars seen
    FP %       = 100 x false confirmed tracks / cars seen          (can exceed 100 with many false tracks)
    break-up % = 100 x cars relabelled / cars seen                 (never above 100)

Table 4.3's counts also add up to the number of cars (49 + 9 = 53 + 5 = 58), so the thesis may mean
FP = cars not correctly tracked / cars; that reading is reported as ``fp_alt_pct`` (= 100 - TP %).

Beside them: relabel events, track precision (100 x correct / confirmed tracks), coverage (the share
of visible car-frames in which a correct track of that car is assigned to it), and the position and
velocity RMSE over the frames where a correct track is assigned to its own car.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np
from scipy.optimize import linear_sum_assignment

THESIS_COLUMNS = ("tp_pct", "fp_pct", "breakup_pct")


@dataclass(frozen=True)
class Scores:
    """Scores of one run; counts are integers, percentages in [0, 100] (FP % may exceed 100)."""

    tp_pct: float
    fp_pct: float
    breakup_pct: float
    fp_alt_pct: float
    cars_seen: int
    cars_tracked: int
    cars_relabelled: int
    false_tracks: int
    correct_tracks: int
    confirmed_tracks: int
    relabel_events: int
    track_precision_pct: float
    coverage_pct: float
    pos_rmse_m: float
    vel_rmse_mps: float
    n_matched_frames: int
    mean_false_tracks_per_frame: float
    # per-frame position error [m] of correct tracks on their car: frame numbers (F,) and RMSE (F,)
    # over the matched pairs of that frame (NaN where none). Not part of to_dict().
    series_frames: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64), repr=False, compare=False)
    series_pos_rmse_m: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False, compare=False)

    def to_dict(self) -> dict:
        """The scalar scores (JSON-able)."""
        return {k: v for k, v in asdict(self).items() if not k.startswith("series_")}


def _pct(num: int, den: int) -> float:
    return float(100.0 * num / den) if den > 0 else float("nan")


def frame_matches(track_xy: np.ndarray, truth_xy: np.ndarray, max_dist: float) -> tuple[np.ndarray, np.ndarray]:
    """One-to-one assignment within ``max_dist``: index arrays (rows into tracks, cols into truth)."""
    if len(track_xy) == 0 or len(truth_xy) == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    d = np.linalg.norm(track_xy[:, None, :] - truth_xy[None, :, :], axis=-1)
    cost = np.where(d <= max_dist, d, 1e9)
    r, c = linear_sum_assignment(cost)
    ok = d[r, c] <= max_dist
    return r[ok].astype(np.int64), c[ok].astype(np.int64)


def _groups(frame: np.ndarray, frames: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Row order sorted by frame and the [start, stop) of each of ``frames`` in it."""
    order = np.argsort(frame, kind="stable")
    f = frame[order]
    return order, np.searchsorted(f, frames, side="left"), np.searchsorted(f, frames, side="right")


def assign_frames(t_frame, t_xy, g_frame, g_xy, match_distance_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Per-frame one-to-one pairs: (track rows (P,), truth rows (P,)), in frame order."""
    frames = np.union1d(t_frame, g_frame)
    t_order, t_lo, t_hi = _groups(t_frame, frames)
    g_order, g_lo, g_hi = _groups(g_frame, frames)
    rows_t, rows_g = [], []
    for k in range(len(frames)):
        ti, gi = t_order[t_lo[k]:t_hi[k]], g_order[g_lo[k]:g_hi[k]]
        r, c = frame_matches(t_xy[ti], g_xy[gi], match_distance_m)
        rows_t.append(ti[r])
        rows_g.append(gi[c])
    if not rows_t:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    return np.concatenate(rows_t).astype(np.int64), np.concatenate(rows_g).astype(np.int64)


def track_cars(t_id: np.ndarray, pair_tid: np.ndarray, pair_vid: np.ndarray,
                correct_fraction: float) -> dict[int, int]:
    """Correct tracks: {track id: its car}, from the per-frame pairs (thesis-form rule 3): t_id (Q,) the confirmed
    rows' track ids, pair_tid / pair_vid (P,) the track and vehicle id of each per-frame pair."""
    ids, life = np.unique(t_id, return_counts=True)
    best: dict[int, int] = {}
    for tid, n_life in zip(ids, life):
        vids = pair_vid[pair_tid == tid]
        if len(vids):
            v, counts = np.unique(vids, return_counts=True)
            j = int(np.argmax(counts))
            if counts[j] >= correct_fraction * n_life:
                best[int(tid)] = int(v[j])
    return best


def _relabels(pair_tid: np.ndarray, pair_vid: np.ndarray) -> dict[int, int]:
    """{car: number of label changes} over its assigned confirmed tracks (pairs in frame order)."""
    out = {}
    for vid in np.unique(pair_vid):
        labels = pair_tid[pair_vid == vid]
        out[int(vid)] = int(np.count_nonzero(labels[1:] != labels[:-1]))
    return out


def score_run(truth: dict[str, np.ndarray], tracks: dict[str, np.ndarray],
              match_distance_m: float = 3.0, correct_fraction: float = 0.5) -> Scores:
    """Score one run (definitions in the module docstring).

    truth: ``frame (N,)``, ``vehicle_id (N,)``, ``xy (N, 2)`` [m], ``v (N, 2)`` [m/s] (ego excluded) and
    optionally ``visible (N,) bool`` (hit by at least one beam in that frame; default all True).
    tracks: ``frame (Q,)``, ``track_id (Q,)``, ``confirmed (Q,) bool``, ``xy (Q, 2)``, ``v (Q, 2)``.
    """
    conf = np.asarray(tracks["confirmed"], dtype=bool)
    t_frame, t_id = np.asarray(tracks["frame"])[conf], np.asarray(tracks["track_id"])[conf]
    t_xy, t_v = np.asarray(tracks["xy"])[conf], np.asarray(tracks["v"])[conf]
    g_frame, g_id, g_xy, g_v = (np.asarray(truth[k]) for k in ("frame", "vehicle_id", "xy", "v"))
    visible = np.asarray(truth.get("visible", np.ones(len(g_frame), bool)), dtype=bool)

    rt, rg = assign_frames(t_frame, t_xy, g_frame, g_xy, match_distance_m)
    pair_tid, pair_vid = t_id[rt], g_id[rg]
    best = track_cars(t_id, pair_tid, pair_vid, correct_fraction)
    relabels = _relabels(pair_tid, pair_vid)

    seen = set(np.unique(g_id[visible]).tolist())
    cars_tracked = seen & set(best.values())
    cars_relabelled = {v for v, n in relabels.items() if n > 0 and v in seen}
    n_confirmed = len(np.unique(t_id))
    n_false = n_confirmed - len(best)

    good = np.array([best.get(int(t), -99) == int(v) for t, v in zip(pair_tid, pair_vid)], dtype=bool)
    rows_t, rows_g = rt[good], rg[good]
    err2 = np.sum((t_xy[rows_t] - g_xy[rows_g]) ** 2, axis=1)
    if len(rows_t):
        pos = float(np.sqrt(np.mean(err2)))
        vel = float(np.sqrt(np.mean(np.sum((t_v[rows_t] - g_v[rows_g]) ** 2, axis=1))))
    else:
        pos = vel = float("nan")
    frames = np.union1d(t_frame, g_frame)
    at = np.searchsorted(frames, g_frame[rows_g])
    cnt = np.bincount(at, minlength=len(frames))
    with np.errstate(invalid="ignore", divide="ignore"):
        series = np.where(cnt > 0, np.sqrt(np.bincount(at, weights=err2, minlength=len(frames))
                                           / np.maximum(cnt, 1)), np.nan)

    false_rows = ~np.isin(t_id, np.fromiter(best, np.int64, len(best)))
    n_seen = len(seen)
    return Scores(
        tp_pct=_pct(len(cars_tracked), n_seen), fp_pct=_pct(n_false, n_seen),
        breakup_pct=_pct(len(cars_relabelled), n_seen),
        fp_alt_pct=_pct(n_seen - len(cars_tracked), n_seen),
        cars_seen=n_seen, cars_tracked=len(cars_tracked), cars_relabelled=len(cars_relabelled),
        false_tracks=n_false, correct_tracks=len(best), confirmed_tracks=n_confirmed,
        relabel_events=int(sum(relabels.values())),
        track_precision_pct=_pct(len(best), n_confirmed),
        coverage_pct=_pct(int(np.count_nonzero(visible[rows_g])), int(np.count_nonzero(visible))),
        pos_rmse_m=pos, vel_rmse_mps=vel, n_matched_frames=int(len(rows_t)),
        mean_false_tracks_per_frame=float(false_rows.sum() / max(len(np.unique(g_frame)), 1)),
        series_frames=frames.astype(np.int64), series_pos_rmse_m=series,
    )


def format_table(rows: dict[str, Scores]) -> str:
    """Plain-text score table, one row per run label: the thesis-table form, then the other scores."""
    head = (f"{'run':<24} {'cars':>5} {'tracked':>7} {'false':>5} {'TP %':>7} {'FP %':>7} {'break-up %':>10} | "
            f"{'relabels':>8} {'prec. %':>7} {'cover %':>7} {'pos RMSE m':>10} {'vel RMSE m/s':>12}")
    lines = [head, "-" * len(head)]
    for label, s in rows.items():
        lines.append(
            f"{label:<24} {s.cars_seen:5d} {s.cars_tracked:7d} {s.false_tracks:5d} {s.tp_pct:7.2f} "
            f"{s.fp_pct:7.2f} {s.breakup_pct:10.2f} | {s.relabel_events:8d} {s.track_precision_pct:7.2f} "
            f"{s.coverage_pct:7.2f} {s.pos_rmse_m:10.3f} {s.vel_rmse_mps:12.3f}")
    lines.append("left of |, the thesis's form (Tables 4.3, 5.4): cars seen (hit by a beam), cars correctly tracked, "
                 "false confirmed tracks, TP/FP/break-up % per car seen;\nright of |, ours: relabel events, "
                 "precision = correct / confirmed tracks, cover = visible car-frames with a correct track")
    return "\n".join(lines)
