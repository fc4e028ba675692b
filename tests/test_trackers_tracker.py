"""End-to-end tracker runs on seeded two-target scenarios, step contract, registry."""

import warnings

import numpy as np
import pytest

from roadtrack import trackers
from roadtrack.trackers import (FILTERS, ParamError, available_trackers, cv_noise_gain, cv_transition, make_tracker,
                      parse_tracker_name)
from roadtrack.trackers.initiation import single_point
from roadtrack.trackers.registry import WRAPPERS

DT = 0.1


def two_targets(seed, kind, n=100, lam=1e-3, pd=0.9, sigma_w=0.3, sigma_a=0.5, lateral=3.5):
    """Truth X (n, 2, 4) and measurement lists for two NCV cars at 10 Hz, and Poisson clutter of density lam
    [m^-2] in a 60 m x 30 m window that follows them. kind: 'crossing' (lanes cross at t = 2.5 s, closing at
    4 m/s) or 'parallel' (side by side, `lateral` m apart, 25 m/s). Generators are spawned from one seed."""
    rng_truth, rng_det, rng_noise, rng_clut = [np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(4)]
    if kind == "crossing":
        x = np.array([[0.0, -5.0, 20.0, 2.0], [0.0, 5.0, 20.0, -2.0]])
    else:
        x = np.array([[0.0, 0.0, 25.0, 0.0], [0.0, lateral, 25.0, 0.0]])
    A, G = cv_transition(DT), cv_noise_gain(DT)
    X = np.empty((n, 2, 4))
    Zs = []
    for k in range(n):
        X[k] = x
        det = rng_det.random(2) < pd
        z = x[det, :2] + sigma_w * rng_noise.normal(size=(int(det.sum()), 2))
        clutter = x[:, :2].mean(axis=0) + rng_clut.uniform(-1, 1, size=(rng_clut.poisson(lam * 1800), 2)) * [30.0, 15.0]
        Zs.append(np.concatenate([z, clutter]))
        x = x @ A.T + rng_truth.normal(0.0, sigma_a, size=(2, 2)) @ G.T
    return X, Zs


def run(tracker, Zs):
    tracks, nid, hist = (), 0, []
    for Z in Zs:
        r = tracker.step(tracks, Z, DT, nid)
        tracks, nid = r.tracks, r.next_id
        hist.append(r)
    return hist


def coverage(X, hist, radius=2.0):
    """Per frame and target: label and error of the nearest confirmed track within `radius` (-1 / nan if none)."""
    ids = np.full((len(hist), 2), -1)
    err = np.full((len(hist), 2), np.nan)
    for k, h in enumerate(hist):
        conf = [t for t in h.tracks if t.confirmed]
        for i in range(2):
            if conf:
                d = np.array([np.linalg.norm(t.state.x[:2] - X[k, i, :2]) for t in conf])
                j = int(np.argmin(d))
                if d[j] < radius:
                    ids[k, i], err[k, i] = conf[j].id, d[j]
    return ids, err


@pytest.mark.parametrize("kind", ["crossing", "parallel"])
def test_jpda_kf_confirms_both_targets_and_tracks_them_accurately(kind):
    """Seeds 0-3, clutter 1e-3 m^-2 (1.8 points per scan): both targets covered by confirmed tracks within 15
    scans; afterwards covered in >= 85% of target-scans with position RMSE <= 0.45 m (sigma_w = 0.3 m)."""
    tracker = make_tracker("jpda-kf", clutter_density=1e-3)
    for seed in range(4):
        X, Zs = two_targets(seed, kind)
        ids, err = coverage(X, run(tracker, Zs))
        both = np.flatnonzero((ids >= 0).all(axis=1))
        assert both.size and both[0] <= 15, (seed, both[:1])
        after = err[both[0]:]
        assert np.mean(np.isfinite(after)) >= 0.85, seed
        assert np.sqrt(np.nanmean(after**2)) <= 0.45, seed


def test_exclusive_score_mode_keeps_duplicate_confirmed_tracks_rare():
    """With score_mode='exclusive', a tentative track gets no score from a measurement another track holds,
    so at most 3 confirmed tracks exist at any scan for the 2 targets (seeds 0-3, both scenarios)."""
    tracker = make_tracker("jpda-kf", clutter_density=1e-3, score_mode="exclusive")
    for kind in ("crossing", "parallel"):
        for seed in range(4):
            X, Zs = two_targets(seed, kind)
            hist = run(tracker, Zs)
            assert max(sum(t.confirmed for t in h.tracks) for h in hist) <= 3, (kind, seed)
            ids, _ = coverage(X, hist)
            assert (ids[20:] >= 0).mean() >= 0.85, (kind, seed)


def test_exclusive_score_increment_formula():
    """Two tracks gate one measurement; each track's increment weights L_i by 1 - W[other, i]."""
    tracker = make_tracker("jpda-kf", score_mode="exclusive")
    kf = tracker.filter
    s1 = kf.initial_state(*single_point(np.array([0.0, 0.0]), kf.measurement, 1.0))
    s2 = kf.initial_state(*single_point(np.array([0.5, 0.0]), kf.measurement, 1.0))
    tracks = (trackers.Track(0, s1, 0.0, 0.0, False, 1, 1, 0), trackers.Track(1, s2, 0.0, 0.0, False, 1, 1, 0))
    r = tracker.step(tracks, np.array([[0.2, 0.1]]), DT, 2)
    ap = tracker.association
    ll = trackers.log_gaussian((np.array([0.2, 0.1]) - r.info.z_hat)[:, None, :], r.info.S)  # (2, 1)
    for t, other in ((0, 1), (1, 0)):
        L = ap.pd * np.exp(ll[t, 0]) / ap.clutter_density * (1 - r.info.W[other, 0])
        assert abs(r.tracks[t].score - np.log(1 - ap.pd * tracker.pg + L)) <= 1e-12


def test_empty_frames_and_no_tracks():
    tracker = make_tracker("jpda-kf", initiation="single")
    r = tracker.step((), np.zeros((0, 2)), DT, 5)
    assert r.tracks == () and r.next_id == 5 and r.info.W.shape == (0, 0) and r.info.S.shape == (0, 2, 2)
    r = tracker.step((), np.array([[1.0, 2.0], [30.0, 2.0]]), DT, 5)
    assert [t.id for t in r.tracks] == [5, 6] and r.next_id == 7
    r2 = tracker.step(r.tracks, np.zeros((0, 2)), DT, r.next_id)
    assert r2.info.W.shape == (2, 0)
    np.testing.assert_array_equal(r2.info.w0, [1.0, 1.0])
    pred = tracker.filter.predict(r.tracks[0].state, DT)
    np.testing.assert_array_equal(r2.tracks[0].state.x, pred.x)  # a miss leaves the prediction
    np.testing.assert_array_equal(r2.tracks[0].state.P, pred.P)
    assert r2.tracks[0].misses_in_a_row == 1 and r2.tracks[0].age == 2
    assert abs(r2.tracks[0].score - (r.tracks[0].score + np.log(1 - 0.9 * tracker.pg))) <= 1e-12


def test_non_finite_measurements_raise_one_line_value_error():
    tracker = make_tracker("jpda-kf")
    with pytest.raises(ValueError, match=r"non-finite rows \[1, 3\]") as e:
        tracker.step((), np.array([[0.0, 0.0], [np.nan, 1.0], [2.0, 2.0], [np.inf, 0.0]]), DT, 0)
    assert "\n" not in str(e.value)
    with pytest.raises(ValueError, match="shape"):
        tracker.step((), np.zeros((3, 3)), DT, 0)
    with pytest.raises(ValueError, match="dt"):
        tracker.step((), np.zeros((0, 2)), float("nan"), 0)


def test_step_info_describes_the_predicted_tracks():
    X, Zs = two_targets(0, "crossing", n=12)
    tracker = make_tracker("jpda-kf", clutter_density=1e-3)
    hist = run(tracker, Zs)
    prev, r = hist[-2], hist[-1]
    live = [t for t in prev.tracks if not t.candidate]
    np.testing.assert_array_equal(r.info.ids, [t.id for t in live])
    for t, tr in enumerate(live):
        z_hat, S = tracker.filter.predicted_measurement(tracker.filter.predict(tr.state, DT))
        np.testing.assert_allclose(r.info.z_hat[t], z_hat, rtol=0, atol=1e-12)
        np.testing.assert_allclose(r.info.S[t], S, rtol=0, atol=1e-12)
    np.testing.assert_allclose(r.info.W.sum(axis=1) + r.info.w0, 1.0, atol=1e-12)
    assert np.all(r.info.W[~r.info.gated] == 0.0)
    survivors_and_deleted = {t.id for t in r.tracks} | {t.id for t in r.deleted}
    assert set(r.info.ids.tolist()) <= survivors_and_deleted


def test_runs_are_deterministic():
    X, Zs = two_targets(1, "parallel", n=40, lam=1e-2)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", trackers.JPDAOverflowWarning)
        a = run(make_tracker("jpda-kf"), Zs)
        b = run(make_tracker("jpda-kf"), Zs)
    for ra, rb in zip(a, b):
        assert [t.id for t in ra.tracks] == [t.id for t in rb.tracks]
        for ta, tb in zip(ra.tracks, rb.tracks):
            assert np.array_equal(ta.state.x, tb.state.x) and np.array_equal(ta.state.P, tb.state.P)
            assert ta.score == tb.score


# ---- registry --------------------------------------------------------------------------------------------------

def test_registry_names_and_errors():
    assert {"gnn-kf", "jpda-kf", "nn-kf", "pda-kf", "jpda-ekf"} <= set(available_trackers())
    assert parse_tracker_name("jpda-kf") == (None, "jpda", "kf")
    with pytest.raises(ValueError) as e:
        make_tracker("jpda-ukf")
    for valid in ("'gnn'", "'jpda'", "'nn'", "'pda'", "'kf'"):
        assert valid in str(e.value)
    with pytest.raises(ParamError, match=r"sigma_q: unknown parameter for tracker 'pda-kf'.*'sigma_v'"):
        make_tracker("pda-kf", sigma_q=1.0)
    with pytest.raises(ParamError, match="management.score_mode: 'best' is not allowed; allowed: gate, exclusive"):
        make_tracker("pda-kf", score_mode="best")
    with pytest.raises(ParamError, match="associator.pd: expected a finite number, got '0.9'"):
        make_tracker("pda-kf", pd="0.9")
    with pytest.raises(ParamError, match="filter.sigma_v: -1.0 is not allowed; must be >= 0"):
        make_tracker("pda-kf", filter={"sigma_v": -1.0})
    with pytest.raises(ParamError, match="filter.gate_alpha: unknown key; allowed: detection_R, motion, "):
        make_tracker("pda-kf", associator={"gate_alpha": 9.0, "kind": "pda"}, filter={"gate_alpha": 1.0})
    with pytest.raises(ParamError, match="filter.kind: is set by the tracker name 'pda-kf'"):
        make_tracker("pda-kf", filter={"kind": "ekf"})
    with pytest.raises(ParamError, match="management.kind: unknown manager 'mofn'"):
        make_tracker("pda-kf", management={"kind": "mofn"})
    t = make_tracker("nn-kf", sigma_v=1.5, sigma_w=0.2, pd=0.8)
    assert (t.filter.motion.sigma_v, t.filter.measurement.sigma_w, t.association.pd) == (1.5, 0.2, 0.8)
    assert t.associator is trackers.ASSOCIATORS["nn"]
    typed = make_tracker("nn-kf", filter={"sigma_v": 1.5, "sigma_w": 0.2}, associator={"pd": 0.8})
    assert typed.filter == t.filter and typed.association == t.association


def test_registry_parses_hyphenated_filter_names_and_wrappers(monkeypatch):
    monkeypatch.setitem(FILTERS, "gvbl-test", FILTERS["kf"])
    monkeypatch.setitem(WRAPPERS, "wrap", lambda base: ("kf", {"sigma_v": 0.5}))
    assert parse_tracker_name("jpda-gvbl-test") == (None, "jpda", "gvbl-test")
    assert parse_tracker_name("wrap-pda-gvbl-test") == ("wrap", "pda", "gvbl-test")
    assert "wrap-jpda-kf" in available_trackers()
    assert make_tracker("wrap-jpda-kf").filter.motion.sigma_v == 0.5  # the wrapper's table
    assert make_tracker("wrap-jpda-kf", sigma_v=1.0).filter.motion.sigma_v == 1.0  # overridden key by key


@pytest.mark.parametrize("name", available_trackers())
def test_every_registered_tracker_runs_a_20_frame_scenario(name):
    """Contract over the registry: two well-separated cars (15 m apart) with clutter; after 20 scans each has a
    confirmed track within 0.6 m and every step's weights are a distribution."""
    X, Zs = two_targets(0, "parallel", n=20, lam=1e-3, lateral=15.0)
    hist = run(make_tracker(name, clutter_density=1e-3), Zs)
    for h in hist:
        np.testing.assert_allclose(h.info.W.sum(axis=1) + h.info.w0, 1.0, atol=1e-12)
    ids, err = coverage(X, hist)
    assert np.all(err[-1] <= 0.6), err[-1]


def test_two_point_initiation_pairs_candidates_within_reach():
    tracker = make_tracker("jpda-kf")  # initiation="two_point" by default
    p = dict(sigma_w=tracker.filter.measurement.sigma_w, v_max=tracker.management.v_max,
             new_target_density=tracker.management.new_target_density, pd=tracker.association.pd,
             clutter_density=tracker.association.clutter_density)
    p = type("P", (), p)
    r1 = tracker.step((), np.array([[0.0, 0.0], [50.0, 0.0]]), DT, 3)
    assert [t.candidate for t in r1.tracks] == [True, True] and r1.next_id == 3
    assert [t.id for t in r1.tracks] == [-1, -1]
    # first candidate moves 2.5 m (25 m/s): paired; second has no partner within reach: dropped;
    # the far measurement becomes a new candidate.
    r2 = tracker.step(r1.tracks, np.array([[2.5, 0.1], [200.0, 0.0]]), DT, r1.next_id)
    new = [t for t in r2.tracks if not t.candidate]
    assert [t.id for t in new] == [3] and r2.next_id == 4
    np.testing.assert_allclose(new[0].state.x, [2.5, 0.1, 25.0, 1.0], atol=1e-12)
    R = p.sigma_w**2
    np.testing.assert_allclose(new[0].state.P[0, 2], R / DT, rtol=1e-12)
    np.testing.assert_allclose(new[0].state.P[2, 2], 2 * R / DT**2, rtol=1e-12)
    reach = p.v_max * DT + 3 * np.sqrt(2) * p.sigma_w
    expected = np.log(p.new_target_density / p.clutter_density) + np.log(p.pd / (np.pi * reach**2) / p.clutter_density)
    assert abs(new[0].score - expected) <= 1e-12
    cands = [t for t in r2.tracks if t.candidate]
    assert len(cands) == 1 and np.allclose(cands[0].state.x[:2], [200.0, 0.0])
    # a measurement farther than reach from every candidate never pairs
    r3 = tracker.step(r2.tracks, np.array([[200.0 + reach + 0.01, 0.0]]), DT, r2.next_id)
    assert r3.next_id == r2.next_id


def test_kind_sub_tables_apply_only_to_their_kind_and_reach_imm_modes():
    tables = dict(filter={"sigma_w": 0.5, "svsf": {"psi": 0.2}, "gvbl-svsf": {"psi_max": 5.0}},
                  associator={"apda": {"psi_max": 1.0}, "jpda": {"method": "enumerate"}})
    assert make_tracker("pda-svsf", **tables).filter.psi == (0.2, 0.2)
    kf = make_tracker("jpda-kf", **tables)
    assert kf.filter.measurement.sigma_w == 0.5 and kf.association.method == "enumerate"
    assert make_tracker("apda-gvbl-svsf", **tables).association.psi_max == 1.0
    imm = make_tracker("imm-pda-svsf", **tables)  # CV mode: svsf, CT mode: gvbl-svsf
    assert imm.filter.filters[0].psi == (0.2, 0.2) and imm.filter.filters[1].psi_max == 5.0
    with pytest.raises(ParamError, match="filter.svsf.psy: unknown key; allowed: artificial_pda, covariance, detection_R, gamma"):
        make_tracker("jpda-kf", filter={"svsf": {"psy": 0.2}})  # a typo in another kind's table still fails
    with pytest.raises(ParamError, match="filter.svsf.psi: -1.0 is not allowed"):
        make_tracker("jpda-svsf", filter={"svsf": {"psi": -1.0}})
    lenient = make_tracker("jpda-kf", filter={"psi": 0.2, "sigma_v": 1.0}, associator={"form": "thesis"}, lenient=True)
    assert lenient.filter.motion.sigma_v == 1.0  # keys of another tracker dropped, its own kept


@pytest.mark.parametrize("case", ["same", "sizes", "keys", "empty", "scalar-vs-1"])
def test_info_diagnostics_equal_the_track_by_track_expansion(case):
    """The tracker's batched `info` columns equal the per-track expansion (values, NaNs, column order) whether the
    states share keys and sizes or not."""
    from types import SimpleNamespace

    from roadtrack.trackers.tracker import _expand, info_diagnostics

    rng = np.random.default_rng(7)

    def info(t):
        if case == "empty":
            return {}
        d = {"mu": rng.uniform(size=2), "cv.psi_z": rng.uniform(size=(2,)), "step": float(rng.uniform())}
        if case == "sizes" and t == 2:
            d["mu"] = rng.uniform(size=3)
        if case == "keys" and t % 2:
            d = {"step": d["step"], "extra": rng.uniform(size=2)}
        if case == "keys" and t == 3:
            d = {"late": 1.0, **d}
        if case == "scalar-vs-1" and t == 1:
            d["step"] = np.array([0.25])
        return d

    states = [SimpleNamespace(info=info(t)) for t in range(5)]
    got, ref = {"pd": np.ones(5)}, {"pd": np.ones(5)}
    info_diagnostics(states, got)
    for t, s in enumerate(states):
        for name, v in s.info.items():
            _expand(name, v, 5, ref, t)
    assert list(got) == list(ref)
    for k in ref:
        np.testing.assert_array_equal(got[k], ref[k])
    assert case == "empty" or len(ref) > 3
