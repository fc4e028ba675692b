"""Shared intervals and paired tests (testbed/common/stats.py): Wilson against scipy's binomtest, the t interval by
hand, McNemar against the binomial and by hand, the paired t against ttest_rel, the paired bootstrap by hand and
against scipy's bootstrap."""
import math

import numpy as np
import pytest
from scipy import stats as sps

from roadtrack.testbed.common.stats import mcnemar, mean_ci, paired_bootstrap, paired_t, wilson


@pytest.mark.parametrize("k, n", [(0, 10), (3, 10), (10, 10), (47, 100), (1, 1)])
def test_wilson_equals_scipys(k, n):
    ref = sps.binomtest(k, n).proportion_ci(confidence_level=0.95, method="wilson")
    lo, hi = wilson(k, n)
    assert float(lo) == pytest.approx(ref.low, abs=1e-12) and float(hi) == pytest.approx(ref.high, abs=1e-12)


def test_wilson_bounds_are_exact_at_zero_and_all():
    """k = n gives an upper bound of exactly 1 and k = 0 a lower bound of exactly 0 (30/30 gave 1 - 1.1e-16, a
    negative error bar in a plot)."""
    for n in range(1, 300):
        assert wilson(n, n)[1] == 1.0 and wilson(0, n)[0] == 0.0


def test_wilson_vectorised_nan_for_empty_and_refuses_bad_counts():
    lo, hi = wilson(np.array([0, 5, 0]), np.array([0, 10, 4]))
    assert math.isnan(lo[0]) and math.isnan(hi[0]) and lo[1] < 0.5 < hi[1] and lo[2] == 0.0
    with pytest.raises(ValueError, match="0 <= k <= n"):
        wilson(3, 2)


def test_mean_ci_is_the_student_t_interval():
    x = [1.0, 2.0, 4.0, np.nan]
    n, m, sd, lo, hi = mean_ci(x)
    half = sps.t.ppf(0.975, 2) * np.std([1, 2, 4], ddof=1) / math.sqrt(3)
    assert n == 3 and m == pytest.approx(7 / 3) and lo == pytest.approx(m - half) and hi == pytest.approx(m + half)
    assert mean_ci([5.0])[0] == 1 and math.isnan(mean_ci([5.0])[3]) and mean_ci([])[0] == 0


# ------------------------------------------------------------------ paired statistics (common random numbers)
def test_mcnemar_counts_discordant_pairs_and_equals_scipys_binomial():
    a = np.array([1, 1, 1, 0, 0, 1, 0, 1, 1, 0], dtype=bool)
    b = np.array([1, 0, 0, 0, 1, 0, 0, 0, 1, 0], dtype=bool)
    r = mcnemar(a, b)
    assert (r.b, r.c, r.n) == (4, 1, 10)  # a only: runs 1, 2, 5, 7; b only: run 4
    assert r.p == pytest.approx(sps.binomtest(4, 5, 0.5).pvalue, abs=1e-15)
    assert r.p == pytest.approx(2 * (1 + 5) / 32, abs=1e-15)  # by hand: 2 P(X <= 1), X ~ Bin(5, 1/2)


@pytest.mark.parametrize("nb, nc, p", [(1, 9, 22 / 1024), (0, 6, 2 / 64), (3, 3, 1.0), (0, 0, 1.0), (10, 0, 2 / 1024)])
def test_mcnemar_exact_p_by_hand(nb, nc, p):
    a = np.array([True] * nb + [False] * nc + [True, False])  # one concordant pair of each kind
    b = np.array([False] * nb + [True] * nc + [True, False])
    r = mcnemar(a, b)
    assert (r.b, r.c) == (nb, nc) and r.p == pytest.approx(p, abs=1e-15)
    assert r.significant() == (p < 0.05)


def test_mcnemar_issue33_example_is_significant_where_wilson_intervals_overlap():
    """200 paired runs, 89 vs 68 lost (44.5 % vs 34 %) with 29 + 8 discordant pairs: the Wilson intervals of the
    two rates overlap, the paired test is significant (binomial 8 of 37 at 1/2)."""
    a = np.zeros(200, dtype=bool)
    b = np.zeros(200, dtype=bool)
    a[:60], b[:60] = True, True  # both lost
    a[60:89] = True  # only the first (29)
    b[89:97] = True  # only the second (8)
    r = mcnemar(a, b)
    assert (int(a.sum()), int(b.sum()), r.b, r.c) == (89, 68, 29, 8)
    assert r.p == pytest.approx(sps.binomtest(8, 37, 0.5).pvalue, rel=1e-12) and r.p < 0.01
    assert wilson(89, 200)[0] < wilson(68, 200)[1]  # the unpaired intervals overlap


def test_mcnemar_refuses_unpaired_shapes():
    with pytest.raises(ValueError, match="equal 1-D"):
        mcnemar(np.zeros(3, bool), np.zeros(4, bool))


def test_paired_t_equals_scipys_ttest_rel_interval():
    rng = np.random.default_rng(3)
    a = rng.normal(2.0, 1.0, 12)
    b = a - 0.3 + rng.normal(0.0, 0.2, 12)
    r = paired_t(a, b)
    ref = sps.ttest_rel(a, b).confidence_interval(0.95)
    assert r.n == 12 and r.test == "paired t 95 % CI"
    assert r.est == pytest.approx(np.mean(a - b), abs=1e-14)
    assert r.lo == pytest.approx(ref.low, abs=1e-12) and r.hi == pytest.approx(ref.high, abs=1e-12)
    assert r.above and not r.below and r.excludes(0.0)


def test_paired_t_by_hand_and_nan_for_one_pair():
    r = paired_t([3.0, 5.0, 4.0], [1.0, 2.0, 2.0])  # d = 2, 3, 2: mean 7/3, sd sqrt(1/3)
    half = sps.t.ppf(0.975, 2) * math.sqrt(1 / 3) / math.sqrt(3)
    assert r.est == pytest.approx(7 / 3) and r.lo == pytest.approx(7 / 3 - half) and r.hi == pytest.approx(7 / 3 + half)
    one = paired_t([1.0], [0.0])
    assert one.n == 1 and math.isnan(one.lo) and not one.below and not one.above


def test_paired_bootstrap_is_seeded_and_equals_a_hand_written_resampling():
    rng = np.random.default_rng(5)
    a, b = rng.normal(1.0, 1.0, 30), rng.normal(0.0, 1.0, 30)
    r1, r2 = paired_bootstrap(a, b, 7), paired_bootstrap(a, b, 7)
    assert (r1.lo, r1.hi) == (r2.lo, r2.hi) and r1.test == "paired bootstrap 95 % CI"
    idx = np.random.default_rng(7).integers(0, 30, size=(2000, 30))
    boot = (a[idx] - b[idx]).mean(axis=1)
    assert r1.est == pytest.approx(np.mean(a - b), abs=1e-14)
    assert r1.lo == pytest.approx(np.percentile(boot, 2.5), abs=1e-14)
    assert r1.hi == pytest.approx(np.percentile(boot, 97.5), abs=1e-14)


def test_paired_bootstrap_agrees_with_scipys_percentile_bootstrap_and_the_t_interval():
    rng = np.random.default_rng(11)
    a = rng.normal(5.0, 2.0, 200)
    b = a + rng.normal(-0.5, 1.0, 200)
    mine = paired_bootstrap(a, b, 1, n_boot=20000)
    ref = sps.bootstrap((a, b), lambda x, y, axis=-1: np.mean(x - y, axis=axis), paired=True, n_resamples=20000,
                        method="percentile", rng=np.random.default_rng(2)).confidence_interval
    assert mine.lo == pytest.approx(ref.low, abs=0.01) and mine.hi == pytest.approx(ref.high, abs=0.01)
    t = paired_t(a, b)
    assert mine.lo == pytest.approx(t.lo, abs=0.02) and mine.hi == pytest.approx(t.hi, abs=0.02)


def test_paired_bootstrap_of_an_rmse_ratio_resamples_runs_jointly():
    """stat over axis 1: RMSE(a) / RMSE(b) from per-run mean squared errors; equal pairs give ratio 1 exactly."""
    mse = np.array([1.0, 4.0, 9.0, 2.0, 5.0])
    ratio = lambda A, B: np.sqrt(A.mean(axis=1) / B.mean(axis=1))  # noqa: E731
    r = paired_bootstrap(mse, mse, 0, stat=ratio)
    assert (r.est, r.lo, r.hi) == (1.0, 1.0, 1.0)
    r2 = paired_bootstrap(4.0 * mse, mse, 0, stat=ratio)
    assert (r2.est, r2.lo, r2.hi) == pytest.approx((2.0, 2.0, 2.0), abs=1e-12)
    with pytest.raises(ValueError, match="equal non-empty"):
        paired_bootstrap(mse, mse[:3], 0)


def test_paired_bootstrap_of_several_statistics_shares_its_resamples():
    """A stat of k values gives arrays (k,), each equal to the scalar bootstrap of that column (same seed)."""
    rng = np.random.default_rng(2)
    a, b = rng.normal(size=(25, 3)), rng.normal(size=(25, 3))
    both = paired_bootstrap(a, b, 4, stat=lambda A, B: (A - B).mean(axis=1))
    assert both.est.shape == both.lo.shape == (3,)
    for j in range(3):
        one = paired_bootstrap(a[:, j], b[:, j], 4)
        assert (both.est[j], both.lo[j], both.hi[j]) == pytest.approx((one.est, one.lo, one.hi), abs=1e-14)
    assert both.below == bool(np.all(both.hi < 0)) and paired_bootstrap(a[:1], b[:1], 0).n == 1
