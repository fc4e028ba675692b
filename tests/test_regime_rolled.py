"""The tracker's rolled KS windows (trackers.trackloss.regime: window_rows, roll_windows, assess_rolled) give the
same regime tests, bit for bit, as the windows rebuilt from the tracks' histories (assess_windows on
windows_from_histories, the implementation they replace, kept here as `reference_regimes`): on random constructed
windows (hypothesis), and scan by scan on real runs (cut_in_out, highway_benchmark; several trackers)."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import roadtrack.trackers.tracker as tracker_module
from roadtrack.trackers import make_tracker
from roadtrack.trackers.trackloss import regime as rg

FIELDS = ("n", "alpha", "d_n", "D_T", "D_L", "gamma", "sigma_n", "volume", "lam", "pd")


def assert_same_test(a: rg.RegimeTest, b: rg.RegimeTest) -> None:
    """Every statistic equal (==, no tolerance), the counts equal and of one dtype."""
    for f in FIELDS:
        assert getattr(a, f) == getattr(b, f), f
    for f in ("counts_ng", "counts_cg"):
        x, y = getattr(a, f), getattr(b, f)
        assert x.dtype == y.dtype and np.array_equal(x, y), f
    assert a.verdict == b.verdict


def reference_regimes(cfg: rg.RegimeConfig, lam: float, nz: int, states: list, histories: list) -> list:
    """The tracker's regimes as computed before the rolled windows (Tracker._regimes up to this change): every
    scan, each track's window rebuilt from its history."""
    T = len(states)
    ready = [t for t in range(T) if len(histories[t]) >= states[t].n]
    out = [rg.advance(s, None, cfg) for s in states]
    for n in sorted({states[t].n for t in ready}):
        group = [t for t in ready if states[t].n == n]
        root_det, d2_scans, pd = rg.windows_from_histories([histories[t] for t in group], n)
        gammas = np.atleast_1d(rg.gamma_best_fast(lam * root_det.mean(axis=1), nz))
        tests = rg.assess_windows(root_det, d2_scans, pd, lam, nz, [rg.alpha_of(states[t], cfg) for t in group],
                                  gammas)
        for t, test in zip(group, tests):
            out[t] = rg.advance(states[t], test, cfg)
    return out


# ------------------------------------------------------------------------------------------ constructed windows
@st.composite
def windows(draw):
    """T tracks over K scans: root_det (K, T), pd (K, T), d2: K arrays (T, M_k) (M_k from 0 to 14; chi-square-like,
    far, zero and repeated values), lam, nz, k (kept distances), n (window) and capacity (>= n)."""
    seed = draw(st.integers(0, 2 ** 32 - 1))
    rng = np.random.default_rng(seed)
    T, n, nz = draw(st.integers(1, 6)), draw(st.integers(1, 12)), draw(st.integers(1, 3))
    K = n + draw(st.integers(0, 8))
    k = draw(st.sampled_from([1, 2, 3, rg.WINDOW_LOW]))
    capacity = n + draw(st.integers(0, 3))
    lam = float(10 ** rng.uniform(-4, 0))
    root_det = rng.uniform(0.02, 4.0, (K, T)) * rng.choice([1.0, 30.0], (K, T), p=[0.9, 0.1])
    pd = rng.uniform(0.0, 1.0, (K, T))
    d2 = []
    for _ in range(K):
        M = int(rng.integers(0, 15))
        a = rng.chisquare(nz, (T, M)) * rng.choice([0.3, 1.0, 10.0, 100.0], (T, M))
        a[rng.random((T, M)) < 0.1] = 0.0
        if M > 1:
            a[:, 1] = a[:, 0]  # ties
        d2.append(a)
    return root_det, pd, d2, lam, nz, k, n, capacity


@settings(max_examples=150, deadline=None)
@given(windows())
def test_rolled_windows_give_the_tests_of_the_rebuilt_windows_bit_for_bit(case):
    root_det, pd, d2, lam, nz, k, n, capacity = case
    K, T = root_det.shape
    rolled = [None] * T
    for s in range(K):
        rolled = rg.roll_windows(rolled, rg.window_rows(root_det[s], pd[s], d2[s], k), capacity)
        assert rolled.shape == (T, capacity, 3 + k)
        assert all(rg.window_holds(w, min(s + 1, capacity)) and not rg.window_holds(w, min(s + 1, capacity) - 1)
                   for w in rolled)
        if s + 1 < n:
            continue
        a = s + 1 - n
        scans = [[d2[j][t] for j in range(a, s + 1)] for t in range(T)]
        rd = np.ascontiguousarray(root_det[a:s + 1].T)  # (T, n) as the histories give it: one summation order
        gammas = np.atleast_1d(rg.gamma_best_fast(lam * rd.mean(axis=1), nz))
        alphas = [0.05, 0.01] * T
        ref = rg.assess_windows(rd, scans, np.ascontiguousarray(pd[a:s + 1].T), lam, nz, alphas[:T], gammas)
        got = rg.assess_rolled(np.stack([w[len(w) - n:] for w in rolled]), lam, nz, alphas[:T],
                               lambda t, j: scans[t][j])
        for x, y in zip(got, ref):
            assert_same_test(x, y)


def test_distances_on_the_gates_themselves_are_counted_as_the_rebuilt_windows_count_them():
    """d2 equal to gamma_best (NG) or to a scan's CG threshold lies in the gate (<=); with k = 1 most counts come
    from the full distances."""
    rng = np.random.default_rng(3)
    T, n, nz, lam = 4, 6, 2, 0.02
    root_det, pd = rng.uniform(0.1, 2.0, (T, n)), rng.uniform(0.5, 1.0, (T, n))
    g = np.atleast_1d(rg.gamma_best_fast(lam * root_det.mean(axis=1), nz))
    thr_cg = g[:, None] / rg.constant_gate_scale(root_det, root_det.mean(axis=1)[:, None], nz)
    scans = [[np.array([g[t], thr_cg[t, j], np.nextafter(g[t], np.inf), 0.5 * g[t], thr_cg[t, j]])
              for j in range(n)] for t in range(T)]
    for k in (1, 2, 8):
        rows = np.stack([np.concatenate([rg.window_rows(root_det[t, j:j + 1], pd[t, j:j + 1], scans[t][j][None], k)
                                         for j in range(n)]) for t in range(T)])
        got = rg.assess_rolled(rows, lam, nz, [0.05] * T, lambda t, j: scans[t][j])
        for x, y in zip(got, rg.assess_windows(root_det, scans, pd, lam, nz, [0.05] * T, g)):
            assert_same_test(x, y)
            assert x.counts_ng.min() >= 2  # g itself and 0.5 g at least


def test_a_window_rebuilt_from_records_equals_the_rolled_one():
    """Full (capacity 5 after 9 scans) and padded (capacity 12): window_of_records gives the rolled window, padding
    included; window_holds knows how many scans it holds."""
    from roadtrack.trackers.tracker import ScanRecord

    rng = np.random.default_rng(4)
    recs, rolled = [], {5: [None], 12: [None]}
    for _ in range(9):
        a = rng.normal(size=(2, 2))
        S = a @ a.T + np.eye(2)
        d2 = rng.chisquare(2, int(rng.integers(0, 12)))
        rd = float(np.sqrt(np.linalg.det(S)))
        recs.append(ScanRecord(nu_c=np.zeros(2), S=S, n_gated=0, gate_volume=1.0, nis=0.0, detected=False,
                               pd=float(rng.uniform()), d2=d2, root_det=rd if rng.random() < 0.5 else None))
        for cap in rolled:
            rolled[cap] = rg.roll_windows(rolled[cap], rg.window_rows(np.array([rd]), np.array([recs[-1].pd]),
                                                                     d2[None]), cap)
    np.testing.assert_array_equal(rg.window_of_records(recs[-5:], capacity=5), rolled[5][0])
    np.testing.assert_array_equal(rg.window_of_records(recs, capacity=12), rolled[12][0])
    assert rg.window_holds(rolled[5][0], 5) and rg.window_holds(rolled[12][0], 9)
    assert not any(rg.window_holds(rolled[12][0], L) for L in (0, 3, 8, 10, 12, 13))
    assert rg.window_holds(rg.window_of_records((), capacity=4), 0)
    with pytest.raises(ValueError, match="exceed the capacity"):
        rg.window_of_records(recs, capacity=3)


# ------------------------------------------------------------------------------------------ real runs
@pytest.fixture(scope="module")
def frames():
    """Sensed frames of two real scenarios (highway-env traffic, LiDAR, perception)."""
    from roadtrack import testbed

    out = {}
    for name, seconds in (("cut_in_out", 10.0), ("highway_benchmark", 4.0)):
        scn = testbed.load_scenario(name, {"duration_s": seconds})
        out[name] = (scn, list(testbed.sense(scn)))
    return out


def _checked_run(monkeypatch, frames, scenario: str, tracker) -> int:
    """Run `tracker` on the scenario's frames through the testbed, checking after every Tracker.step each live
    input track's new regime state against reference_regimes on its new history. Returns the tests compared."""
    from roadtrack import testbed

    compared = [0]
    step = tracker_module.Tracker.step

    def checked(self, tracks, Z, *args, **kwargs):
        res = step(self, tracks, Z, *args, **kwargs)
        after = {tr.id: tr for tr in res.tracks + res.deleted if not tr.candidate}
        live = [tr for tr in tracks if not tr.candidate and tr.id in after]
        cfg, nz = self.management.regime_config, self.filter.measurement.ndim
        lam = self.management.regime_clutter_density or self.association.clutter_density
        prev = [tr.regime_state or rg.initial_state(cfg) for tr in live]
        ref = reference_regimes(cfg, lam, nz, prev, [after[tr.id].history for tr in live])
        for tr, r in zip(live, ref):
            got = after[tr.id].regime_state
            assert (got.label, got.n, got.level, got.flips, got.unique_run) == \
                (r.label, r.n, r.level, r.flips, r.unique_run)
            assert after[tr.id].regime == r.label
            if r.last is not None and r.last is not (tr.regime_state and tr.regime_state.last):
                assert_same_test(got.last, r.last)
                compared[0] += 1
        return res

    monkeypatch.setattr(tracker_module.Tracker, "step", checked)
    scn, fr = frames[scenario]
    for _ in testbed.track(fr, tracker, scn):
        pass
    return compared[0]


@pytest.mark.parametrize("scenario", ["cut_in_out", "highway_benchmark"])
@pytest.mark.parametrize("tracker", ["jpda-kf", "imm-pda-kf", "apda-svsf", "nn-kf"])
def test_the_tracker_regimes_equal_the_history_rebuilt_ones_on_real_runs(monkeypatch, frames, scenario, tracker):
    assert _checked_run(monkeypatch, frames, scenario, tracker) > 50


def test_the_recount_on_full_distances_is_exercised_and_exact_on_a_real_run(monkeypatch, frames):
    """One distance kept per scan: nearly every count reaches it and is recounted on the record's d2."""
    calls = [0]
    low_counts = rg._low_counts

    def counting(windows, thr, d2_of):
        def d2(t, j):
            calls[0] += 1
            return d2_of(t, j)
        return low_counts(windows, thr, d2)

    monkeypatch.setattr(tracker_module, "WINDOW_LOW", 1)
    monkeypatch.setattr(rg, "_low_counts", counting)
    assert _checked_run(monkeypatch, frames, "cut_in_out", "jpda-kf") > 50
    assert calls[0] > 100


def test_an_adaptive_window_is_rolled_exactly(monkeypatch, frames):
    """Adaptive n (paper 002 §V-F): windows of several lengths in one scan, capacity regime_n_max."""
    from roadtrack.testbed.tracking.builtin import BuiltinTracker

    trk = make_tracker("pda-kf", sigma_w=0.3, clutter_density=1e-3, management={
        "regime_adaptive": True, "regime_n": 10, "regime_n_min": 5, "regime_n_max": 40})
    assert _checked_run(monkeypatch, frames, "cut_in_out", BuiltinTracker(trk)) > 50


def test_tracks_without_a_rolled_window_get_one_rebuilt_from_their_history(frames):
    """A track whose regime state has lost its window (made outside Tracker.step) gets it rebuilt from its
    history: the next scan's regime is the same as with the window."""
    from dataclasses import replace

    scn, fr = frames["cut_in_out"]
    trk = make_tracker("jpda-kf", sigma_w=0.3, clutter_density=1e-3)
    tracks, nid = (), 0
    for f in fr[:60]:
        res = trk.step(tracks, f.detections.z, 0.1, nid)
        tracks, nid = res.tracks, res.next_id
    stripped = tuple(replace(tr, regime_state=replace(tr.regime_state, window=None)) if tr.regime_state else tr
                     for tr in tracks)
    z = fr[60].detections.z
    a, b = trk.step(tracks, z, 0.1, nid), trk.step(stripped, z, 0.1, nid)
    assert sum(tr.regime_state.last is not None for tr in a.tracks if tr.regime_state) >= 2
    for x, y in zip(a.tracks, b.tracks):
        assert x.regime == y.regime
        if x.regime_state is not None and x.regime_state.last is not None:
            assert_same_test(x.regime_state.last, y.regime_state.last)
            np.testing.assert_array_equal(x.regime_state.window, y.regime_state.window)
