"""Shared intervals (testbed/common/stats.py): Wilson against scipy's binomtest, the t interval by hand."""
import math

import numpy as np
import pytest
from scipy import stats as sps

from testbed.common.stats import mean_ci, wilson


@pytest.mark.parametrize("k, n", [(0, 10), (3, 10), (10, 10), (47, 100), (1, 1)])
def test_wilson_equals_scipys(k, n):
    ref = sps.binomtest(k, n).proportion_ci(confidence_level=0.95, method="wilson")
    lo, hi = wilson(k, n)
    assert float(lo) == pytest.approx(ref.low, abs=1e-12) and float(hi) == pytest.approx(ref.high, abs=1e-12)


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
