"""testbed.scoring.mot_metrics against Stone Soup 1.9.1 (GOSPA oracle), real TrackEval 1.3.0 and hand arithmetic."""
from __future__ import annotations

import datetime

import numpy as np
import pytest
from stonesoup.metricgenerator.ospametric import GOSPAMetric
from stonesoup.types.array import StateVector
from stonesoup.types.state import State

from roadtrack.testbed.scoring.mot_metrics import METRIC_KEYS, trackeval_metrics, gospa, mot_metrics, visible_truth

T0 = datetime.datetime(2024, 1, 1)
N_ALPHA = 19  # HOTA alphas 0.05, 0.10, ..., 0.95


def rows(frame, ids, xy, id_key):
    return {"frame": np.asarray(frame, np.int64).reshape(-1), id_key: np.asarray(ids, np.int64).reshape(-1),
            "xy": np.asarray(xy, np.float64).reshape(-1, 2)}


def truth_rows(frame, ids, xy):
    return rows(frame, ids, xy, "vehicle_id")


def track_rows(frame, ids, xy):
    return rows(frame, ids, xy, "track_id")


def states(points: np.ndarray, k: int = 0) -> list[State]:
    return [State(StateVector(list(pt)), timestamp=T0 + datetime.timedelta(seconds=k)) for pt in points]


def straight_lines(n_vehicles: int, n_frames: int) -> np.ndarray:
    """(n_frames, n_vehicles, 2) [m]: vehicles 4 m apart laterally, 25 m/s at 10 Hz."""
    x = 2.5 * np.arange(n_frames)[:, None] + 30.0 * np.arange(n_vehicles)[None, :]
    y = np.broadcast_to(4.0 * np.arange(n_vehicles)[None, :], x.shape)
    return np.stack([x, y], axis=-1)


# --------------------------------------------------------------------------- GOSPA vs Stone Soup

CASES = [(seed, n, m) for seed in range(6) for n, m in [(0, 4), (3, 0), (4, 4), (2, 6), (6, 3)]]


@pytest.mark.parametrize("c,p", [(3.0, 2.0), (5.0, 1.0), (2.0, 3.0)])
@pytest.mark.parametrize("seed,n,m", CASES)
def test_gospa_frame_equals_stonesoup(seed, n, m, c, p):
    rng = np.random.default_rng(seed)
    X = rng.uniform(0.0, 8.0, (n, 2))      # truth
    Y = rng.uniform(0.0, 8.0, (m, 2))      # estimates: some pairs inside c, some beyond
    total, loc, missed, false = gospa(X, Y, c, p)

    ss = GOSPAMetric(c=c, p=p, switching_penalty=0)
    value = ss.compute_gospa_metric(states(Y), states(X))[0].value
    assert total == pytest.approx(value["distance"], rel=1e-9, abs=1e-12)
    assert loc == pytest.approx(value["localisation"], rel=1e-9, abs=1e-12)
    assert missed == pytest.approx(value["missed"], rel=1e-9, abs=1e-12)
    assert false == pytest.approx(value["false"], rel=1e-9, abs=1e-12)
    assert total ** p == pytest.approx(loc + missed + false, rel=1e-9, abs=1e-12)


def test_gospa_both_empty_is_zero():
    # Stone Soup cannot take two empty sets (no timestamp), so the value is asserted directly.
    assert gospa(np.zeros((0, 2)), np.zeros((0, 2)), 3.0, 2.0) == (0.0, 0.0, 0.0, 0.0)


def test_run_gospa_is_frame_mean_of_stonesoup_values():
    """mot_metrics' GOSPA terms are the means over all n_frames of Stone Soup's per-timestep values."""
    rng = np.random.default_rng(7)
    n_frames, c, p = 25, 3.0, 2.0
    g, t = [], []
    for f in range(n_frames):
        if f % 6 == 5:
            continue                                    # frames with neither truth nor tracks
        n = 0 if f % 6 == 1 else int(rng.integers(1, 5))
        m = 0 if f % 6 == 3 else int(rng.integers(1, 6))
        X = rng.uniform(0.0, 10.0, (n, 2))
        Y = np.concatenate([X[: min(n, m)] + rng.normal(0.0, 1.0, (min(n, m), 2)),
                            rng.uniform(0.0, 10.0, (m - min(n, m), 2))])
        g += [(f, i, *x) for i, x in enumerate(X)]
        t += [(f, 50 + j, *y) for j, y in enumerate(Y)]
    g, t = np.array(g), np.array(t)
    truth = truth_rows(g[:, 0], g[:, 1], g[:, 2:])
    tracks = track_rows(t[:, 0], t[:, 1], t[:, 2:])
    res = mot_metrics(truth, tracks, n_frames, gospa_c=c, gospa_p=p)

    ss = GOSPAMetric(c=c, p=p, switching_penalty=0)
    truth_states = [s for f, _, *xy in g for s in states(np.array([xy]), int(f))]
    track_states = [s for f, _, *xy in t for s in states(np.array([xy]), int(f))]
    per_step = ss.compute_over_time(track_states, list(t[:, 1].astype(int)),
                                    truth_states, list(g[:, 1].astype(int))).value
    assert len(per_step) == n_frames - 4                # Stone Soup skips the 4 empty frames
    for ours, key in [("gospa", "distance"), ("gospa_localisation", "localisation"),
                      ("gospa_missed", "missed"), ("gospa_false", "false")]:
        expected = sum(step.value[key] for step in per_step) / n_frames
        assert res[ours] == pytest.approx(expected, rel=1e-9)


# --------------------------------------------------------------------------- TrackEval scenarios

def test_perfect_tracking_scores_one():
    n_frames, n_veh = 40, 5
    pos = straight_lines(n_veh, n_frames)
    alive = np.ones((n_frames, n_veh), bool)
    alive[:10, 3] = False                               # vehicle 3 enters late
    alive[30:, 1] = False                               # vehicle 1 leaves early
    alive[20] = False                                   # a frame with nobody
    f, v = np.nonzero(alive)
    truth = truth_rows(f, 7 + 3 * v, pos[f, v])
    tracks = track_rows(f, 1000 - v, pos[f, v])         # one (different) id per vehicle
    res = mot_metrics(truth, tracks, n_frames)
    for key in ("hota", "deta", "assa", "loca", "mota", "motp", "idf1"):
        assert res[key] == pytest.approx(1.0, abs=1e-9), key
    for key in ("id_switches", "gospa", "gospa_localisation", "gospa_missed", "gospa_false"):
        assert res[key] == pytest.approx(0.0, abs=1e-12), key
    assert set(res) == set(METRIC_KEYS)
    assert all(type(val) is float for val in res.values())


def test_id_switch_halfway():
    """Vehicle 0 keeps track 100 all along; vehicle 1 is track 101 for frames 0-9, track 102 for 10-19.

    GT dets = 40, tracker dets = 40, all at zero distance, the vehicles 30 m apart (similarity 0).
    Identity: best one-to-one id map {0: 100, 1: 101} (or 102): IDTP = 20 + 10 = 30, IDFN = 10 (vehicle 1's
    frames under 102), IDFP = 10 (track 102's rows). IDF1 = 2 IDTP / (2 IDTP + IDFP + IDFN)
    = 2 IDTP / (GT dets + tracker dets) = 60 / 80 = 0.75.
    CLEAR: TP = 40, FN = FP = 0, IDSW = 1 -> MOTA = 1 - IDSW / GT = 1 - 1/40.
    HOTA (similarity 1 for every TP, so the same at every alpha): DetA = 1; per TP the association IoU is
    1 for the 20 (0, 100) matches and 10 / (10 + 10 + 0) = 0.5 for the 10 (1, 101) and 10 (1, 102) ones,
    AssA = (20 * 1 + 20 * 0.5) / 40 = 0.75, HOTA = sqrt(0.75).
    """
    n_frames = 20
    pos = straight_lines(2, n_frames)
    f = np.repeat(np.arange(n_frames), 2)
    v = np.tile([0, 1], n_frames)
    truth = truth_rows(f, v, pos[f, v])
    tid = np.where(v == 0, 100, np.where(f < 10, 101, 102))
    res = mot_metrics(truth, track_rows(f, tid, pos[f, v]), n_frames)

    gt_dets, tr_dets, idtp = 40, 40, 30
    assert res["id_switches"] == 1.0
    assert res["idf1"] == pytest.approx(2 * idtp / (gt_dets + tr_dets), abs=1e-12)
    assert res["idf1"] == pytest.approx(0.75, abs=1e-12)
    assert res["mota"] == pytest.approx(1.0 - 1.0 / gt_dets, abs=1e-12)
    assert res["deta"] == pytest.approx(1.0, abs=1e-12)
    assert res["assa"] == pytest.approx(0.75, abs=1e-12)
    assert res["hota"] == pytest.approx(np.sqrt(0.75), abs=1e-12)
    assert res["gospa"] == pytest.approx(0.0, abs=1e-12)   # GOSPA ignores identities (switching penalty 0)


def test_track_beyond_match_distance_is_miss_plus_false():
    n_frames, c, p = 20, 3.0, 2.0
    pos = straight_lines(1, n_frames)[:, 0]
    f = np.arange(n_frames)
    truth = truth_rows(f, np.zeros(n_frames), pos)
    tracks = track_rows(f, np.full(n_frames, 9), pos + [0.0, 10.0])   # always 10 m to the side
    res = mot_metrics(truth, tracks, n_frames, similarity_scale_m=3.0, gospa_c=c, gospa_p=p)
    gt, fn, fp = 20, 20, 20
    assert res["mota"] == pytest.approx(1.0 - (fn + fp) / gt, abs=1e-12)         # = -1
    for key in ("hota", "deta", "assa", "idf1", "motp", "id_switches", "gospa_localisation"):
        assert res[key] == pytest.approx(0.0, abs=1e-12), key
    assert res["gospa_missed"] == pytest.approx(c ** p / 2, rel=1e-12)          # 4.5 m^2 per frame
    assert res["gospa_false"] == pytest.approx(c ** p / 2, rel=1e-12)
    assert res["gospa"] == pytest.approx(c, rel=1e-12)                           # (c^p/2 + c^p/2)^(1/p)


@pytest.mark.parametrize("offset,clear_match,n_alpha_matched", [(1.4, True, 10), (1.6, False, 9)])
def test_clear_threshold_is_half_the_similarity_scale(offset, clear_match, n_alpha_matched):
    """Constant offset d, similarity s = 1 - d/3. CLEAR/Identity match iff s >= 0.5 (d <= 1.5 m);
    HOTA matches at the alphas <= s: 10 of them (0.05..0.50) for s = 0.533, 9 (0.05..0.45) for s = 0.467,
    with HOTA_alpha = 1 there and 0 elsewhere."""
    n_frames = 20
    pos = straight_lines(1, n_frames)[:, 0]
    f = np.arange(n_frames)
    res = mot_metrics(truth_rows(f, np.zeros(n_frames), pos),
                      track_rows(f, np.ones(n_frames), pos + [offset, 0.0]), n_frames)
    s = 1.0 - offset / 3.0
    assert res["hota"] == pytest.approx(n_alpha_matched / N_ALPHA, abs=1e-12)
    # LocA is s at the matched alphas and 1 (TrackEval's no-TP value) at the others.
    assert res["loca"] == pytest.approx((n_alpha_matched * s + N_ALPHA - n_alpha_matched) / N_ALPHA, abs=1e-12)
    if clear_match:
        assert res["mota"] == pytest.approx(1.0, abs=1e-12)
        assert res["motp"] == pytest.approx(s, abs=1e-12)
        assert res["idf1"] == pytest.approx(1.0, abs=1e-12)
    else:
        assert res["mota"] == pytest.approx(-1.0, abs=1e-12)
        assert res["motp"] == pytest.approx(0.0, abs=1e-12)
        assert res["idf1"] == pytest.approx(0.0, abs=1e-12)


# --------------------------------------------------------------------------- empty inputs, invariances

EMPTY = {"frame": np.zeros(0, np.int64), "xy": np.zeros((0, 2))}


@pytest.mark.parametrize("case", ["both_empty", "truth_only", "tracks_only", "zero_frames"])
def test_empty_inputs_give_documented_values(case):
    c, p, n_frames = 3.0, 2.0, 10
    f = np.array([0, 0, 3, 4, 4, 4])
    xy = np.arange(12.0).reshape(6, 2) * 7.0
    truth = {**EMPTY, "vehicle_id": np.zeros(0, np.int64)}
    tracks = {**EMPTY, "track_id": np.zeros(0, np.int64)}
    if case == "truth_only":
        truth = truth_rows(f, [1, 2, 1, 1, 2, 3], xy)
    if case == "tracks_only":
        tracks = track_rows(f, [1, 2, 1, 1, 2, 3], xy)
    if case == "zero_frames":
        n_frames = 0
    res = mot_metrics(truth, tracks, n_frames, gospa_c=c, gospa_p=p)
    assert set(res) == set(METRIC_KEYS)
    assert all(np.isfinite(val) for val in res.values())
    expected = {"hota": 0.0, "deta": 0.0, "assa": 0.0, "loca": 1.0, "mota": 0.0, "motp": 0.0, "idf1": 0.0,
                "id_switches": 0.0, "gospa": 0.0, "gospa_localisation": 0.0, "gospa_missed": 0.0,
                "gospa_false": 0.0}
    per_frame_count = np.bincount(f, minlength=n_frames)                # 2, 0, 0, 1, 3, 0, ...
    if case == "truth_only":
        expected["gospa_missed"] = c ** p / 2 * len(f) / n_frames
        expected["gospa"] = np.mean(np.sqrt(c ** p / 2 * per_frame_count))
    if case == "tracks_only":
        expected["mota"] = -float(len(f))                               # 1 - FP / max(1, GT = 0)
        expected["gospa_false"] = c ** p / 2 * len(f) / n_frames
        expected["gospa"] = np.mean(np.sqrt(c ** p / 2 * per_frame_count))
    for key, val in expected.items():
        assert res[key] == pytest.approx(val, abs=1e-12), key


def test_row_order_does_not_matter():
    rng = np.random.default_rng(3)
    n_frames = 30
    pos = straight_lines(4, n_frames)
    f, v = np.nonzero(rng.random((n_frames, 4)) < 0.8)
    truth = truth_rows(f, v, pos[f, v])
    tid = v + 10 * (f > 15) * (v == 2)                                   # one id switch
    tracks = track_rows(f, tid, pos[f, v] + rng.normal(0.0, 0.6, (len(f), 2)))
    ref = mot_metrics(truth, tracks, n_frames)
    pg, pt = rng.permutation(len(f)), rng.permutation(len(f))
    res = mot_metrics({k: a[pg] for k, a in truth.items()}, {k: a[pt] for k, a in tracks.items()}, n_frames)
    for key in METRIC_KEYS:
        assert res[key] == pytest.approx(ref[key], rel=1e-12, abs=1e-12), key
    assert 0.0 < ref["hota"] < 1.0


def test_trackeval_construction_prints_nothing(capsys):
    trackeval_metrics.cache_clear()
    hota, clear, ident = trackeval_metrics()
    assert capsys.readouterr().out == ""
    assert clear.threshold == 0.5 and ident.threshold == 0.5
    assert len(hota.array_labels) == N_ALPHA


def test_rejects_malformed_rows():
    truth = truth_rows([0, 0], [4, 4], [[0.0, 0.0], [5.0, 0.0]])          # id 4 twice in frame 0
    tracks = {**EMPTY, "track_id": np.zeros(0, np.int64)}
    with pytest.raises(ValueError, match="appears twice"):
        mot_metrics(truth, tracks, 1)
    with pytest.raises(ValueError, match="frames must lie"):
        mot_metrics(truth_rows([5], [1], [[0.0, 0.0]]), tracks, 5)


# --------------------------------------------------------------------------- visible truth


def _occlusion_case(coast: bool):
    """Two cars over 4 frames; car 2 is hidden in frames 2-3. T1 follows car 1 throughout; T2 follows
    car 2 in frames 0-1 and, when ``coast``, through the occlusion too. T9 is a false track in frame 3."""
    pos = straight_lines(2, 4)
    f = np.repeat(np.arange(4), 2)
    v = np.tile([0, 1], 4)
    truth = truth_rows(f, v + 1, pos[f, v])
    truth["visible"] = ~((v == 1) & (f >= 2))
    on = (v == 0) | (f < 2) | coast
    tracks = track_rows(np.append(f[on], 3), np.append(v[on] + 1, 9),
                        np.vstack([pos[f, v][on] + [0.3, 0.0], [[500.0, 0.0]]]))
    return truth, tracks


@pytest.mark.parametrize("coast", [False, True])
def test_visible_truth_treats_hidden_cars_as_dont_care(coast):
    """Hand-worked: visible GT = 6 (car 1 x 4, car 2 x 2), all GT = 8, one false track row.
    Visible: 6 TP, 1 FP -> MOTA = 1 - 1/6 whether or not T2 coasts (its hidden-car rows are dropped).
    All truth: lost T2 -> 2 FN + 1 FP -> MOTA = 1 - 3/8; coasting T2 -> 1 FP -> MOTA = 1 - 1/8."""
    truth, tracks = _occlusion_case(coast)
    g_vis, t_vis = visible_truth(truth, tracks, similarity_scale_m=3.0)
    assert len(g_vis["frame"]) == 6 and len(t_vis["frame"]) == 7
    assert set(g_vis) == set(truth) and set(t_vis) == set(tracks)
    vis = mot_metrics(g_vis, t_vis, 4)
    full = mot_metrics({k: truth[k] for k in ("frame", "vehicle_id", "xy")}, tracks, 4)
    assert vis["mota"] == pytest.approx(1.0 - 1.0 / 6.0, abs=1e-12)
    assert vis["idf1"] == pytest.approx(2 * 6 / (6 + 7), abs=1e-12)
    assert vis["gospa_false"] == pytest.approx(4.5 / 4, abs=1e-12)       # c^p/2 once in 4 frames
    assert vis["gospa_missed"] == pytest.approx(0.0, abs=1e-12)
    assert full["mota"] == pytest.approx(1.0 - (1.0 if coast else 3.0) / 8.0, abs=1e-12)
    assert full["gospa_missed"] == pytest.approx(0.0 if coast else 2 * 4.5 / 4, abs=1e-12)


def test_visible_truth_keeps_a_track_far_from_the_hidden_car():
    """A track 2 m from a hidden car is beyond similarity_scale_m / 2 = 1.5 m: it stays, as a false track."""
    truth = truth_rows([0], [1], [[0.0, 0.0]])
    truth["visible"] = np.array([False])
    _, t_vis = visible_truth(truth, track_rows([0, 0], [5, 6], [[2.0, 0.0], [1.0, 0.0]]), similarity_scale_m=3.0)
    assert t_vis["track_id"].tolist() == [5]
