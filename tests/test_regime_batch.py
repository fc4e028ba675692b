"""assess_windows (the tracker's per-scan batch of KS track-loss tests) against assess_window, track by track."""

import numpy as np
import pytest

from roadtrack.trackers.trackloss.regime import assess_window, assess_windows, gamma_best_fast


@pytest.mark.parametrize("nz", [1, 2, 3])
@pytest.mark.parametrize("seed", range(4))
def test_the_batched_windows_equal_the_single_window_test_to_1e_12(nz, seed):
    rng = np.random.default_rng(seed)
    T, n, lam = 9, int(rng.integers(5, 60)), float(rng.uniform(1e-4, 0.5))
    root_det = rng.uniform(0.05, 3.0, (T, n))
    # per scan 0..6 measurements (some scans empty), distances chi2-like, a few far ones
    d2 = [[rng.chisquare(nz, int(rng.integers(0, 7))) * rng.choice([1.0, 10.0]) for _ in range(n)] for _ in range(T)]
    pd = rng.uniform(0.3, 1.0, (T, n))
    alphas = rng.choice([0.05, 0.01], T)
    gammas = np.atleast_1d(gamma_best_fast(lam * root_det.mean(axis=1), nz))
    batch = assess_windows(root_det, d2, pd, lam, nz, alphas, gammas)
    assert len(batch) == T
    for t, b in enumerate(batch):
        one = assess_window(root_det[t], d2[t], pd[t], lam, nz, alphas[t], gamma=float(gammas[t]))
        np.testing.assert_array_equal(b.counts_ng, one.counts_ng)
        np.testing.assert_array_equal(b.counts_cg, one.counts_cg)
        for f in ("D_T", "D_L", "d_n", "gamma", "sigma_n", "volume", "pd", "alpha", "lam"):
            assert getattr(b, f) == pytest.approx(getattr(one, f), rel=1e-12, abs=1e-12), f
        assert b.n == one.n and b.verdict == one.verdict


def test_no_windows_give_no_tests():
    assert assess_windows(np.zeros((0, 5)), [], np.zeros((0, 5)), 0.1, 2, [], np.zeros(0)) == []


def test_windows_without_any_measurement_count_zero_everywhere():
    T, n = 3, 10
    batch = assess_windows(np.ones((T, n)), [[np.zeros(0)] * n] * T, np.full((T, n), 0.9), 0.01, 2, [0.05] * T,
                           np.full(T, 4.0))
    one = assess_window(np.ones(n), [np.zeros(0)] * n, np.full(n, 0.9), 0.01, 2, 0.05, gamma=4.0)
    for b in batch:
        assert not b.counts_ng.any() and not b.counts_cg.any()
        assert b.D_T == pytest.approx(one.D_T, abs=1e-15) and b.D_L == pytest.approx(one.D_L, abs=1e-15)
        assert b.verdict == one.verdict


def test_windows_from_histories_read_the_stored_root_det_or_compute_it_from_S():
    from roadtrack.trackers.tracker import ScanRecord
    from roadtrack.trackers.trackloss.regime import window_from_history, windows_from_histories

    rng = np.random.default_rng(5)

    def record(stored: bool) -> ScanRecord:
        a = rng.normal(size=(2, 2))
        S = a @ a.T + np.eye(2)
        return ScanRecord(nu_c=np.zeros(2), S=S, n_gated=1, gate_volume=1.0, nis=0.0, detected=True,
                          pd=float(rng.uniform()), d2=rng.chisquare(2, 3),
                          root_det=float(np.sqrt(np.linalg.det(S))) if stored else None)

    histories = [[record(bool(rng.integers(2))) for _ in range(12)] for _ in range(4)]
    root_det, d2, pd = windows_from_histories(histories, 7)
    assert root_det.shape == pd.shape == (4, 7) and root_det.dtype == np.float64
    for t, h in enumerate(histories):
        one = window_from_history(h, 7)
        np.testing.assert_allclose(root_det[t], one[0], rtol=1e-14)
        np.testing.assert_array_equal(pd[t], one[2])
        assert all(np.array_equal(x, y) for x, y in zip(d2[t], one[1]))


def test_mismatched_windows_are_one_clear_error():
    with pytest.raises(ValueError, match="assess_windows needs"):
        assess_windows(np.ones((2, 5)), [[np.zeros(0)] * 5], np.ones((2, 5)), 0.1, 2, [0.05] * 2, np.ones(2))
    with pytest.raises(ValueError, match="assess_windows needs"):
        assess_windows(np.ones(5), [[np.zeros(0)] * 5], np.ones(5), 0.1, 2, [0.05], np.ones(1))


def test_the_batched_ks_distance_equals_the_single_one():
    from roadtrack.trackers.trackloss.ks import ks_distance_counts, ks_distances_counts

    rng = np.random.default_rng(2)
    counts = rng.integers(0, 6, (7, 20))
    cdf = np.sort(rng.uniform(size=(7, 9)), axis=1)
    expect = [ks_distance_counts(c, f) for c, f in zip(counts, cdf)]
    np.testing.assert_array_equal(ks_distances_counts(counts, cdf), expect)
