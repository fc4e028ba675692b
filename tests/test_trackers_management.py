"""Track management: the score (thesis §7.2) thresholds, initial score, increments and decisions, coasting, m-of-n,
duplicate pruning, per-track P_D and the track history, and their effect in a run."""

import math

import numpy as np
import pytest
from scipy.stats import multivariate_normal

from roadtrack.trackers import ManagementParams, gate_probability, initial_score, make_tracker, score_decide, score_increment
from roadtrack.trackers.management import m_of_n_decide

PD, PG, LAM = 0.9, gate_probability(16.0, 2), 1e-2


def test_thresholds_equal_the_sprt_formulas():
    mp = ManagementParams()
    assert abs(mp.confirm_threshold - math.log((1 - 1e-2) / 1e-4)) <= 1e-15
    assert abs(mp.delete_threshold - math.log(1e-2 / (1 - 1e-4))) <= 1e-15
    assert abs(mp.confirm_threshold - 9.2003) <= 1e-4 and abs(mp.delete_threshold - (-4.6051)) <= 1e-4
    miss = -math.log1p(-PD * PG)  # score lost per missed scan
    assert abs(mp.deletion_drop(PD, PG) - 5.5 * miss) <= 1e-12  # coasts through coast_scans = 5 misses
    assert ManagementParams(delta_del=7.5).deletion_drop(PD, PG) == 7.5
    with pytest.raises(ValueError, match="beta_tm: alpha_fc \\+ beta_tm must be < 1"):
        ManagementParams(alpha_fc=0.5, beta_tm=0.6)


def test_initial_score():
    assert abs(initial_score(ManagementParams(), LAM, PD) - math.log(1e-3 / 1e-2)) <= 1e-15
    with_pd = initial_score(ManagementParams(initial_score_pd=True), LAM, PD)
    assert abs(with_pd - (math.log(1e-3 / 1e-2) + math.log(PD))) <= 1e-15


def test_score_increment_equals_the_pda_likelihood_ratio():
    S = np.array([[0.5, 0.1], [0.1, 0.4]])
    nu = np.array([[0.3, -0.2], [1.0, 0.5], [9.0, 9.0]])
    log_n = multivariate_normal(np.zeros(2), S).logpdf(nu)[None]  # (1, 3)
    gated = np.array([[True, True, False]])
    expected = math.log(1 - PD * PG + sum(PD * math.exp(v) / LAM for v in log_n[0, :2]))
    assert abs(score_increment(log_n, gated, PD, PG, LAM)[0] - expected) <= 1e-12
    miss = score_increment(np.zeros((1, 0)), np.zeros((1, 0), dtype=bool), PD, PG, LAM)[0]
    assert abs(miss - math.log(1 - PD * PG)) <= 1e-15


def test_decisions_follow_the_thresholds():
    mp = ManagementParams()
    tc, td, drop = mp.confirm_threshold, mp.delete_threshold, mp.deletion_drop(PD, PG)
    score = np.array([tc, tc - 1e-9, td, td + 1e-9, 20.0, 20.0, 5.0])
    max_score = np.array([tc, tc, 0.0, 0.0, 20.0 + drop, 20.0 + drop - 1e-9, 5.0])
    confirmed = np.array([False, False, False, False, True, True, False])
    c, d = score_decide(score, max_score, confirmed, mp, drop)
    np.testing.assert_array_equal(c, [True, False, False, False, True, True, False])
    np.testing.assert_array_equal(d, [False, False, True, False, True, False, False])


def test_m_of_n_decisions():
    mp = ManagementParams(confirm_m=3, confirm_n=5, coast_scans=2)
    det = np.array([[0, 0, 1, 1, 1], [1, 0, 1, 0, 0], [0, 0, 0, 1, 0], [1, 1, 1, 0, 0], [1, 1, 0, 0, 0]], dtype=bool)
    misses = np.array([0, 2, 1, 2, 3])
    confirmed = np.array([False, False, False, True, True])
    c, d = m_of_n_decide(det, misses, confirmed, mp)
    np.testing.assert_array_equal(c, [True, False, False, True, True])  # 3 of 5 confirms
    np.testing.assert_array_equal(d, [False, True, True, False, True])  # 3 window misses; > coast_scans in a row


def run_single_target(frames_present, frames_total, lam_sim, seed, tracker_lam=1e-2, **params):
    """One NCV target at 25 m/s seen at 10 Hz (P_D = 0.9, sigma_w = 0.3 m) until `frames_present`, then gone;
    Poisson clutter of density lam_sim in a 60 m x 30 m window around it. Returns per-frame StepResults."""
    rng_det, rng_noise, rng_clut = [np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(3)]
    tr = make_tracker("jpda-kf", clutter_density=tracker_lam, **params)
    tracks, nid, out = (), 0, []
    for k in range(frames_total):
        pos = np.array([25.0 * 0.1 * k, 0.0])
        seen = k < frames_present and rng_det.random() < PD
        z = pos + 0.3 * rng_noise.normal(size=(1, 2)) if seen else np.zeros((0, 2))
        clutter = pos + rng_clut.uniform(-1, 1, size=(rng_clut.poisson(lam_sim * 1800), 2)) * [30.0, 15.0]
        r = tr.step(tracks, np.concatenate([z, clutter]), 0.1, nid)
        tracks, nid = r.tracks, r.next_id
        out.append(r)
    return out


@pytest.mark.parametrize("manager, n", [("score", 6), ("m_of_n", 6)])
def test_confirmed_track_coasts_then_is_deleted_a_formula_number_of_frames_after_its_target_disappears(manager, n):
    """Without clutter each missed scan adds ln(1 - P_D P_G); the default deletion drop is 5.5 such scans, so a
    confirmed track coasts through 5 misses (0.5 s: a well-established track survives 3 missed scans) and is deleted at the
    6th; m-of-n deletes after coast_scans + 1 = 6 misses in a row."""
    hist = run_single_target(40, 60, 0.0, seed=3, management={"kind": manager})
    confirmed_ids = {t.id for t in hist[39].tracks if t.confirmed}
    assert len(confirmed_ids) == 1
    gone = [k for k, h in enumerate(hist) if confirmed_ids & {t.id for t in h.deleted}]
    assert gone == [39 + n]
    coasting = [t for t in hist[39 + n - 1].tracks if t.id in confirmed_ids][0]
    assert coasting.misses_in_a_row == n - 1 and coasting.confirmed
    assert [r.detected for r in coasting.history][-(n - 1):] == [False] * (n - 1)
    assert coasting.history_array("n_gated")[-1] == 0 and coasting.history_array("gate_volume")[-1] > 0


def test_deletion_with_clutter_within_bound():
    for seed in range(3):
        hist = run_single_target(40, 70, 1e-3, seed=seed, tracker_lam=1e-3)
        ids = {t.id for t in hist[39].tracks if t.confirmed}
        assert len(ids) >= 1
        gone = min(k for k, h in enumerate(hist) if ids <= {t.id for g in hist[:k + 1] for t in g.deleted})
        assert gone - 39 <= 8, (seed, gone)


@pytest.mark.filterwarnings("ignore::roadtrack.trackers.JPDAOverflowWarning")  # large tentative clusters: documented PDA fallback
def test_clutter_only_run_confirms_few_tracks():
    """100 scans of Poisson clutter (lambda = 1e-2 m^-2, 18 points per scan) with the default parameters:
    the SPRT allows alpha_FC = 1e-4 false confirmations per tentative track; at most 1 is accepted here."""
    rng = np.random.default_rng(99)
    tr = make_tracker("jpda-kf")
    tracks, nid, ever = (), 0, set()
    for _ in range(100):
        Z = rng.uniform(-1, 1, size=(rng.poisson(LAM * 1800), 2)) * [30.0, 15.0]
        r = tr.step(tracks, Z, 0.1, nid)
        tracks, nid = r.tracks, r.next_id
        ever |= {t.id for t in tracks if t.confirmed}
    assert nid >= 100  # many tentative tracks were tried
    assert len(ever) <= 1


def test_per_track_detection_probability_changes_the_score_and_the_weights():
    """P_D = 0 for a track (e.g. hidden behind another car): a missed scan costs it nothing, and the
    function form receives the predicted measurements."""
    hist = run_single_target(20, 20, 0.0, seed=1)
    tr = make_tracker("jpda-kf")
    tracks = tuple(t for t in hist[-1].tracks if t.confirmed)
    seen = []

    def pd_of(z_hat):
        seen.append(z_hat.copy())
        return np.zeros(len(z_hat))

    r = tr.step(tracks, np.zeros((0, 2)), 0.1, 100, pd=pd_of)
    assert seen[0].shape == (1, 2) and r.tracks[0].score == tracks[0].score
    r = tr.step(tracks, np.zeros((0, 2)), 0.1, 100, pd=np.array([0.5]))
    assert abs(r.tracks[0].score - tracks[0].score - math.log(1 - 0.5 * PG)) <= 1e-12
    assert r.info.diagnostics["pd"][0] == 0.5
    with pytest.raises(ValueError, match="in \\[0, 1\\]"):
        tr.step(tracks, np.zeros((0, 2)), 0.1, 100, pd=np.array([1.5]))


def test_duplicate_confirmed_track_is_pruned_and_the_older_label_kept():
    """A second confirmed track sitting on the first (same measurements) is deleted after merge_scans scans."""
    hist = run_single_target(30, 30, 0.0, seed=2)
    tr = make_tracker("jpda-kf")
    first = [t for t in hist[-1].tracks if t.confirmed][0]
    twin = type(first)(id=first.id + 50, state=first.state, score=first.score, max_score=first.score, confirmed=True,
                       age=5, hits=5, misses_in_a_row=0)
    tracks, gone = (first, twin), None
    for k in range(10):
        z = first.state.x[:2] + np.array([2.5 * (k + 1), 0.0])
        r = tr.step(tracks, z[None], 0.1, 200)
        tracks = r.tracks
        if any(t.id == twin.id for t in r.deleted):
            gone = k
            break
    assert gone == tr.management.merge_scans - 1
    assert [t.id for t in tracks if t.confirmed] == [first.id]
    off = make_tracker("jpda-kf", merge_d2=0.0)
    r = off.step((first, twin), (first.state.x[:2] + [2.5, 0.0])[None], 0.1, 200)
    assert len(r.tracks) == 2 and r.tracks[1].duplicate_scans == 0
