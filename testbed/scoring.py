"""TP / FP / track break-up rates (thesis Tables 4.3, 5.4) and RMSE against simulator truth.

Assignment rule (reference thesis-algorithms.md section 10.1, test-bed definition):

1. Every frame, confirmed tracks are assigned one-to-one to true vehicles (ego excluded) by minimum
   total position distance (Hungarian), a pair being allowed only within ``match_distance_m``.
2. A confirmed track is *correct* when it is assigned to one and the same vehicle for at least
   ``correct_fraction`` of the frames of its confirmed life, and *false* otherwise.
   N_ref = N_correct + N_false; TP % = 100 N_correct / N_ref; FP % = 100 N_false / N_ref.
3. A *break-up* is a relabelling: a vehicle assigned to confirmed track A is later assigned to a
   confirmed track B != A. Break-up % = 100 x break-ups / vehicles seen (vehicles that produced at
   least one detection).
4. RMSE of position and velocity over the frames where a correct track is assigned to its vehicle.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np
from scipy.optimize import linear_sum_assignment


@dataclass(frozen=True)
class Scores:
    tp_pct: float
    fp_pct: float
    breakup_pct: float
    n_correct: int
    n_false: int
    n_ref: int
    n_breakups: int
    vehicles_seen: int
    vehicles_tracked: int
    pos_rmse_m: float
    vel_rmse_mps: float
    n_matched_frames: int
    mean_false_tracks_per_frame: float
    # per-frame position error [m] of correct tracks on their vehicle: frame numbers (F,) and RMSE (F,)
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


def score_run(truth: dict[str, np.ndarray], tracks: dict[str, np.ndarray], seen_vehicles: np.ndarray,
              match_distance_m: float = 3.0, correct_fraction: float = 0.5) -> Scores:
    """Score one run.

    truth: ``frame (N,)``, ``vehicle_id (N,)``, ``xy (N, 2)``, ``v (N, 2)`` (ego excluded).
    tracks: ``frame (Q,)``, ``track_id (Q,)``, ``confirmed (Q,) bool``, ``xy (Q, 2)``, ``v (Q, 2)``.
    seen_vehicles: ids of vehicles that produced at least one detection.
    """
    conf = tracks["confirmed"].astype(bool)
    t_frame, t_id = tracks["frame"][conf], tracks["track_id"][conf]
    t_xy, t_v = tracks["xy"][conf], tracks["v"][conf]
    g_frame, g_id, g_xy, g_v = truth["frame"], truth["vehicle_id"], truth["xy"], truth["v"]

    t_order = np.argsort(t_frame, kind="stable")
    g_order = np.argsort(g_frame, kind="stable")
    frames = np.union1d(t_frame, g_frame)
    t_split = np.searchsorted(t_frame[t_order], frames, side="left"), np.searchsorted(t_frame[t_order], frames, side="right")
    g_split = np.searchsorted(g_frame[g_order], frames, side="left"), np.searchsorted(g_frame[g_order], frames, side="right")

    pairs = []  # (frame, track_id, vehicle_id, track_row, truth_row)
    for k in range(len(frames)):
        ti = t_order[t_split[0][k]:t_split[1][k]]
        gi = g_order[g_split[0][k]:g_split[1][k]]
        r, c = frame_matches(t_xy[ti], g_xy[gi], match_distance_m)
        for a, b in zip(ti[r], gi[c]):
            pairs.append((frames[k], t_id[a], g_id[b], a, b))
    pairs_arr = np.array(pairs, dtype=np.int64).reshape(-1, 5)

    # Correct / false confirmed tracks.
    life = {int(i): int(n) for i, n in zip(*np.unique(t_id, return_counts=True))}
    best: dict[int, int] = {}
    for tid in life:
        sel = pairs_arr[pairs_arr[:, 1] == tid]
        if len(sel):
            vids, counts = np.unique(sel[:, 2], return_counts=True)
            j = int(np.argmax(counts))
            if counts[j] >= correct_fraction * life[tid]:
                best[tid] = int(vids[j])
    n_correct = len(best)
    n_false = len(life) - n_correct

    # Break-ups: label changes per vehicle over frames (pairs are in frame order).
    n_breakups = 0
    for vid in np.unique(pairs_arr[:, 2]):
        labels = pairs_arr[pairs_arr[:, 2] == vid, 1]
        n_breakups += int(np.count_nonzero(labels[1:] != labels[:-1]))

    # RMSE over correct tracks assigned to their own vehicle.
    good = np.array([best.get(int(t), -99) == int(v) for t, v in pairs_arr[:, 1:3]], dtype=bool)
    rows_t, rows_g = pairs_arr[good, 3], pairs_arr[good, 4]
    if len(rows_t):
        pos = float(np.sqrt(np.mean(np.sum((t_xy[rows_t] - g_xy[rows_g]) ** 2, axis=1))))
        vel = float(np.sqrt(np.mean(np.sum((t_v[rows_t] - g_v[rows_g]) ** 2, axis=1))))
    else:
        pos = vel = float("nan")

    err2 = np.sum((t_xy[rows_t] - g_xy[rows_g]) ** 2, axis=1)
    sum_e2 = np.bincount(np.searchsorted(frames, pairs_arr[good, 0]), weights=err2, minlength=len(frames))
    cnt = np.bincount(np.searchsorted(frames, pairs_arr[good, 0]), minlength=len(frames))
    with np.errstate(invalid="ignore", divide="ignore"):
        series = np.where(cnt > 0, np.sqrt(sum_e2 / np.maximum(cnt, 1)), np.nan)

    false_ids = np.array([t for t in life if t not in best], dtype=np.int64)
    n_frames = max(len(np.unique(g_frame)), 1)
    seen = np.unique(seen_vehicles)
    return Scores(
        tp_pct=_pct(n_correct, len(life)), fp_pct=_pct(n_false, len(life)),
        breakup_pct=_pct(n_breakups, len(seen)),
        n_correct=n_correct, n_false=n_false, n_ref=len(life), n_breakups=n_breakups,
        vehicles_seen=len(seen), vehicles_tracked=len(set(best.values())),
        pos_rmse_m=pos, vel_rmse_mps=vel, n_matched_frames=int(len(rows_t)),
        mean_false_tracks_per_frame=float(np.isin(t_id, false_ids).sum() / n_frames),
        series_frames=frames.astype(np.int64), series_pos_rmse_m=series,
    )


def format_table(rows: dict[str, Scores]) -> str:
    """Plain-text score table, one row per run label, raw counts beside the percentages."""
    head = f"{'run':<22} {'TP %':>7} {'FP %':>7} {'break-up %':>10}  {'correct/false/ref':>17} " \
           f"{'break-ups':>9} {'seen':>5} {'pos RMSE m':>10} {'vel RMSE m/s':>12}"
    lines = [head, "-" * len(head)]
    for label, s in rows.items():
        lines.append(
            f"{label:<22} {s.tp_pct:7.2f} {s.fp_pct:7.2f} {s.breakup_pct:10.2f}  "
            f"{f'{s.n_correct}/{s.n_false}/{s.n_ref}':>17} {s.n_breakups:9d} {s.vehicles_seen:5d} "
            f"{s.pos_rmse_m:10.3f} {s.vel_rmse_mps:12.3f}"
        )
    return "\n".join(lines)
