"""Standard multi-object tracking metrics: HOTA, CLEAR MOT, Identity (TrackEval) and GOSPA.

All metrics compare confirmed tracks with simulator truth by 2-D position, frame by frame.

HOTA / CLEAR / Identity (TrackEval 1.3.0, called directly on a hand-built sequence dict)
--------------------------------------------------------------------------------------
TrackEval scores pairs by a *similarity* in [0, 1]. Position distance ``d`` [m] is mapped to

    s(d) = max(0, 1 - d / similarity_scale_m),

so ``s = 1`` at zero error, ``s = 0`` at and beyond ``similarity_scale_m`` (the scenario key
``scoring.similarity_scale_m``; by default the match distance, 3 m, so a CLEAR / Identity match, and a
HOTA match at alpha = 0.5, needs ``d <= 1.5 m``).

* HOTA (Luiten et al., "HOTA: A Higher Order Metric for Evaluating Multi-object Tracking", IJCV 2021)
  counts a pair as a match at localisation threshold ``alpha`` when ``s >= alpha``, i.e. when
  ``d <= (1 - alpha) * similarity_scale_m``, for alpha = 0.05, 0.10, ..., 0.95 (19 values: 2.85 m
  down to 0.15 m for the default 3 m). ``hota``, ``deta``, ``assa``, ``loca`` are the means over those 19
  alphas of HOTA_alpha = sqrt(DetA_alpha * AssA_alpha), DetA_alpha, AssA_alpha, LocA_alpha: the values
  TrackEval prints. (So ``hota`` is not ``sqrt(deta * assa)`` in general.)
* CLEAR (Bernardin & Stiefelhagen 2008) and Identity (Ristani et al. 2016) use TrackEval's default
  similarity threshold 0.5: a pair can be matched only when ``s >= 0.5``, i.e. when
  ``d <= similarity_scale_m / 2`` (1.5 m for the default). CLEAR matching prefers the previous frame's
  pairing, then maximum similarity; Identity is a global one-to-one id assignment.
    mota = 1 - (FN + FP + IDSW) / max(1, GT)              GT = number of truth rows
    motp = sum of s over CLEAR matches / max(1, TP)     a similarity, 1 = perfect; when TP > 0 the mean
                                                        matched distance is (1 - motp) * similarity_scale_m [m]
    idf1 = IDTP / max(1, IDTP + 0.5 IDFP + 0.5 IDFN) = 2 IDTP / (GT + Q) when GT + Q > 0
    id_switches = IDSW: a truth matched to a tracker id other than the one it was last matched to.

The reported values are TrackEval's ``combine_sequences`` over our single sequence, i.e. exactly what
TrackEval's Evaluator reports as the combined result: every ratio is recomputed from the counts, also
on the empty-input shortcuts (``eval_sequence`` alone leaves e.g. MOTA at 0 when there is no truth).

GOSPA (Rahmathullah, García-Fernández & Svensson, "Generalized optimal sub-pattern assignment
metric", FUSION 2017, arXiv:1601.05585), alpha = 2, cut-off c, order p
-----------------------------------------------------------------------------------------------
For truth X (n points) and estimates Y (m points) in one frame, with an optimal assignment gamma of
pairs (i, j) with d(x_i, y_j) < c (found by the Hungarian algorithm on min(d, c)^p):

    GOSPA(X, Y)^p = sum_{(i,j) in gamma} d(x_i, y_j)^p  +  c^p/2 * (n - |gamma|)  +  c^p/2 * (m - |gamma|)
                  =          localisation               +         missed         +         false

The three components are reported in this p-th power form [m^p], as Stone Soup 1.9.1's
``GOSPAMetric.compute_gospa_metric`` reports them ('localisation', 'missed', 'false'), and ``gospa``
itself is the p-th root [m] (Stone Soup's 'distance'). A pair at exactly d = c counts as one missed
plus one false object (cost c^p either way), again as Stone Soup does.

``mot_metrics`` averages over all ``n_frames`` frames (a frame with neither truth nor tracks
contributes 0): ``gospa`` = mean_k GOSPA_k [m] and each component = mean_k component_k [m^p]. The
identity loc + missed + false = GOSPA^p holds per frame; after averaging, ``gospa_localisation +
gospa_missed + gospa_false = mean_k GOSPA_k^p >= gospa^p`` (Jensen), with equality when GOSPA_k is
constant over frames. ``gospa_missed / (c^p/2)`` is the mean number of missed vehicles per frame and
``gospa_false / (c^p/2)`` the mean number of false tracks per frame.

Visible truth (the default set of a run)
---------------------------------------
A car the sensor cannot see (out of range, or hidden behind another) cannot be tracked from the
measurements, so counting it as a miss measures the sensor, not the tracker. ``visible_truth`` keeps
the truth rows hit by at least one beam in that frame and treats the hidden ones as *don't care*, as
the MOTChallenge and KITTI benchmarks do with their ignored objects: per frame, tracks are first
assigned one to one (Hungarian) to all truth within ``similarity_scale_m / 2`` (similarity >= 0.5);
tracks assigned to a hidden car are removed (neither true nor false positives), then the hidden
cars. A run reports the metrics on visible truth under the plain names and on all truth with the
suffix ``_all``.

Empty inputs (never an exception, never NaN)
--------------------------------------------
* No truth and no tracks: hota = deta = assa = 0, loca = 1, mota = motp = idf1 = 0, id_switches = 0,
  gospa and its components 0. (TrackEval's conventions: 0 when there is nothing to detect; LocA is 1
  when there is no true positive.)
* Truth only (N rows, no tracks): hota = deta = assa = 0, loca = 1, mota = 0, motp = 0, idf1 = 0,
  gospa_missed = mean_k c^p/2 n_k.
* Tracks only (Q rows, no truth): hota = deta = assa = 0, loca = 1, mota = -Q (1 - FP / max(1, 0)),
  motp = 0, idf1 = 0, gospa_false = mean_k c^p/2 m_k.
* n_frames = 0 (then both inputs must be empty): as "no truth and no tracks".
"""
from __future__ import annotations

import functools

import numpy as np
from scipy.optimize import linear_sum_assignment

METRIC_KEYS = ("hota", "deta", "assa", "loca", "mota", "motp", "idf1", "id_switches",
               "gospa", "gospa_localisation", "gospa_missed", "gospa_false")


@functools.cache
def trackeval_metrics():
    """(HOTA, CLEAR, Identity) TrackEval metric objects, built once (import + construction ~1 s).

    The config dicts switch off TrackEval's printing of its configuration; CLEAR and Identity keep
    TrackEval's default similarity threshold 0.5. HOTA takes no config and prints nothing.
    """
    from trackeval.metrics import CLEAR, HOTA, Identity

    return (HOTA(),
            CLEAR({"THRESHOLD": 0.5, "PRINT_CONFIG": False}),
            Identity({"THRESHOLD": 0.5, "PRINT_CONFIG": False}))


def _gospa_from_distances(d: np.ndarray, c: float, p: float) -> tuple[float, float, float, float]:
    """GOSPA (alpha=2) from a distance matrix ``d (n, m)`` [m], truth rows x estimate columns."""
    n, m = d.shape
    half = c ** p / 2.0
    if n == 0 or m == 0:
        missed, false = half * n, half * m
        return float((missed + false) ** (1.0 / p)), 0.0, float(missed), float(false)
    r, k = linear_sum_assignment(np.minimum(d, c) ** p)
    dd = d[r, k]
    real = dd < c
    n_pairs = int(np.count_nonzero(real))
    loc = float(np.sum(dd[real] ** p))
    missed = half * (n - n_pairs)
    false = half * (m - n_pairs)
    return float((loc + missed + false) ** (1.0 / p)), loc, float(missed), float(false)


def _pairwise(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Euclidean distances ``(len(a), len(b))`` [m] between point sets ``a (n, k)``, ``b (m, k)``."""
    return np.sqrt(np.sum((a[:, None, :] - b[None, :, :]) ** 2, axis=-1))


def gospa(X: np.ndarray, Y: np.ndarray, c: float = 3.0, p: float = 2.0) -> tuple[float, float, float, float]:
    """GOSPA with alpha = 2 between truth ``X (n, 2)`` [m] and estimates ``Y (m, 2)`` [m] in one frame.

    Returns ``(total, localisation, missed, false)``: ``total`` [m] is the metric, the three components
    are in p-th power form [m^p] with ``total**p == localisation + missed + false``;
    ``missed = c^p/2 * (unassigned truths)``, ``false = c^p/2 * (unassigned estimates)`` (see module
    docstring). Either set may be empty (shape ``(0, 2)``); both empty gives all zeros.
    """
    if not (c > 0 and p >= 1):
        raise ValueError(f"GOSPA needs c > 0 and p >= 1, got c={c}, p={p}")
    X = np.asarray(X, dtype=np.float64).reshape(-1, 2)
    Y = np.asarray(Y, dtype=np.float64).reshape(-1, 2)
    return _gospa_from_distances(_pairwise(X, Y), float(c), float(p))


def _check_rows(name: str, frame: np.ndarray, ids: np.ndarray, xy: np.ndarray, n_frames: int) -> None:
    if not (frame.ndim == 1 and ids.shape == frame.shape and xy.shape == (len(frame), 2)):
        raise ValueError(f"{name}: expected frame (N,), id (N,), xy (N, 2); got "
                         f"{frame.shape}, {ids.shape}, {xy.shape}")
    if len(frame) and (frame.min() < 0 or frame.max() >= n_frames):
        raise ValueError(f"{name}: frames must lie in 0..{n_frames - 1}, got {frame.min()}..{frame.max()}")
    if not np.all(np.isfinite(xy)):
        raise ValueError(f"{name}: xy has non-finite values")
    o = np.lexsort((ids, frame))
    dup = (np.diff(frame[o]) == 0) & (np.diff(ids[o]) == 0)
    if np.any(dup):
        k = o[1:][dup][0]
        raise ValueError(f"{name}: id {ids[k]} appears twice in frame {frame[k]}")


def _rows(name: str, rows: dict, id_key: str, n_frames: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``frame (N,) int64``, ``id (N,) int64``, ``xy (N, 2) float64`` of ``rows``, checked."""
    frame = np.asarray(rows["frame"], dtype=np.int64).reshape(-1)
    ids = np.asarray(rows[id_key], dtype=np.int64).reshape(-1)
    xy = np.asarray(rows["xy"], dtype=np.float64).reshape(-1, 2)
    _check_rows(name, frame, ids, xy, n_frames)
    return frame, ids, xy


def visible_truth(truth: dict[str, np.ndarray], tracks: dict[str, np.ndarray],
                  similarity_scale_m: float) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """Visible truth rows, and the tracks less those on hidden cars (see the module docstring).

    truth: ``frame (N,)``, ``vehicle_id (N,)``, ``xy (N, 2)`` [m], ``visible (N,) bool``; tracks:
    ``frame (Q,)``, ``track_id (Q,)``, ``xy (Q, 2)`` [m]. Returns both dicts with the same keys.
    """
    from .rates import assign_frames

    vis = np.asarray(truth["visible"], dtype=bool)
    rt, rg = assign_frames(np.asarray(tracks["frame"]), np.asarray(tracks["xy"]).reshape(-1, 2),
                           np.asarray(truth["frame"]), np.asarray(truth["xy"]).reshape(-1, 2),
                           similarity_scale_m / 2.0)
    keep = np.ones(len(tracks["frame"]), dtype=bool)
    keep[rt[~vis[rg]]] = False
    return ({k: np.asarray(v)[vis] for k, v in truth.items()},
            {k: np.asarray(v)[keep] for k, v in tracks.items()})


def mot_metrics(truth: dict[str, np.ndarray], tracks: dict[str, np.ndarray], n_frames: int,
                similarity_scale_m: float = 3.0, gospa_c: float = 3.0, gospa_p: float = 2.0) -> dict[str, float]:
    """HOTA / CLEAR / Identity (via TrackEval) and GOSPA for one run.

    truth: ``frame (N,) int64``, ``vehicle_id (N,) int64``, ``xy (N, 2) float64`` [m] (ego excluded).
    tracks: ``frame (Q,) int64``, ``track_id (Q,) int64``, ``xy (Q, 2) float64`` [m], confirmed tracks
    only. Frames are ``0 .. n_frames-1``; any frame may lack truth or tracks. An id may appear at most
    once per frame.
    similarity_scale_m: distance [m] at which the TrackEval similarity ``max(0, 1 - d / similarity_scale_m)``
    reaches 0; CLEAR / Identity then match pairs within ``similarity_scale_m / 2``.
    gospa_c [m], gospa_p: GOSPA cut-off and order (alpha = 2).

    Returns a flat dict of floats with keys ``METRIC_KEYS``; definitions, GOSPA averaging and the
    values on empty input are in the module docstring.
    """
    if not similarity_scale_m > 0:
        raise ValueError(f"similarity_scale_m must be > 0, got {similarity_scale_m}")
    if not (gospa_c > 0 and gospa_p >= 1):
        raise ValueError(f"GOSPA needs c > 0 and p >= 1, got c={gospa_c}, p={gospa_p}")
    n_frames = int(n_frames)
    if n_frames < 0:
        raise ValueError(f"n_frames must be >= 0, got {n_frames}")
    g_frame, g_id, g_xy = _rows("truth", truth, "vehicle_id", n_frames)
    t_frame, t_id, t_xy = _rows("tracks", tracks, "track_id", n_frames)

    g_loc = np.zeros(n_frames)
    g_mis = np.zeros(n_frames)
    g_fal = np.zeros(n_frames)
    g_tot = np.zeros(n_frames)

    def similarity(f: int, gi: np.ndarray, ti: np.ndarray) -> np.ndarray:
        d = _pairwise(g_xy[gi], t_xy[ti])
        g_tot[f], g_loc[f], g_mis[f], g_fal[f] = _gospa_from_distances(d, float(gospa_c), float(gospa_p))
        return np.maximum(0.0, 1.0 - d / similarity_scale_m)

    out = trackeval_scores(g_frame, g_id, t_frame, t_id, n_frames, similarity)
    return {**out, "gospa": _mean(g_tot), "gospa_localisation": _mean(g_loc), "gospa_missed": _mean(g_mis),
            "gospa_false": _mean(g_fal)}


def _mean(a: np.ndarray) -> float:
    return float(np.mean(a)) if len(a) else 0.0


def trackeval_scores(g_frame: np.ndarray, g_id: np.ndarray, t_frame: np.ndarray, t_id: np.ndarray, n_frames: int,
                     similarity) -> dict[str, float]:
    """HOTA, DetA, AssA, LocA, MOTA, MOTP, IDF1 and ID switches (TrackEval, module docstring) of truth rows
    (frame (N,), id (N,)) and track rows (frame (Q,), id (Q,)) with ``similarity(frame, truth rows (n,), track rows
    (m,)) -> (n, m)`` in [0, 1] (the rows as indices into the inputs)."""
    # Contiguous ids 0..K-1 (TrackEval indexes count arrays by id) and rows grouped by frame.
    g_uid, g_cid = np.unique(g_id, return_inverse=True)
    t_uid, t_cid = np.unique(t_id, return_inverse=True)
    g_order = np.argsort(g_frame, kind="stable")
    t_order = np.argsort(t_frame, kind="stable")
    g_bounds = np.concatenate(([0], np.cumsum(np.bincount(g_frame, minlength=n_frames))))
    t_bounds = np.concatenate(([0], np.cumsum(np.bincount(t_frame, minlength=n_frames))))
    gt_ids, tr_ids, sims = [], [], []
    for f in range(n_frames):
        gi = g_order[g_bounds[f]:g_bounds[f + 1]]
        ti = t_order[t_bounds[f]:t_bounds[f + 1]]
        gt_ids.append(g_cid[gi])
        tr_ids.append(t_cid[ti])
        sims.append(similarity(f, gi, ti))
    data = {
        "seq": "run", "num_timesteps": n_frames,
        "num_gt_ids": len(g_uid), "num_tracker_ids": len(t_uid),
        "num_gt_dets": len(g_frame), "num_tracker_dets": len(t_frame),
        "gt_ids": gt_ids, "tracker_ids": tr_ids, "similarity_scores": sims,
    }
    hota_m, clear_m, id_m = trackeval_metrics()
    hota = hota_m.combine_sequences({"run": hota_m.eval_sequence(data)})
    clear = clear_m.combine_sequences({"run": clear_m.eval_sequence(data)})
    ident = id_m.combine_sequences({"run": id_m.eval_sequence(data)})
    return {
        "hota": _mean(hota["HOTA"]), "deta": _mean(hota["DetA"]),
        "assa": _mean(hota["AssA"]), "loca": _mean(hota["LocA"]),
        "mota": float(clear["MOTA"]), "motp": float(clear["MOTP"]),
        "idf1": float(ident["IDF1"]), "id_switches": float(clear["IDSW"]),
    }
