"""Gating: batched Mahalanobis distances and Gaussian log-likelihoods against explicit formulas."""

import numpy as np
import pytest
from scipy.stats import chi2, multivariate_normal

from roadtrack.trackers import gate, gate_probability, innovations, log_gaussian, mahalanobis2


def test_batched_distances_and_log_likelihoods_match_explicit_formulas():
    rng = np.random.default_rng(7)
    T, M = 5, 7
    z_hat = rng.normal(size=(T, 2)) * 5
    Z = rng.normal(size=(M, 2)) * 5
    L = rng.normal(size=(T, 2, 2))
    S = L @ np.swapaxes(L, 1, 2) + 0.2 * np.eye(2)
    nu = innovations(z_hat, Z)
    assert nu.shape == (T, M, 2)
    d2 = mahalanobis2(nu, S)
    ll = log_gaussian(nu, S)
    for t in range(T):
        for j in range(M):
            v = Z[j] - z_hat[t]
            assert abs(d2[t, j] - v @ np.linalg.inv(S[t]) @ v) <= 1e-10 * max(1.0, d2[t, j])
            assert abs(ll[t, j] - multivariate_normal(z_hat[t], S[t]).logpdf(Z[j])) <= 1e-10 * max(1.0, abs(ll[t, j]))
    np.testing.assert_array_equal(gate(d2, 16.0), d2 <= 16.0)


def test_empty_batches_have_the_right_shapes():
    assert mahalanobis2(np.zeros((0, 3, 2)), np.zeros((0, 2, 2))).shape == (0, 3)
    assert log_gaussian(np.zeros((2, 0, 2)), np.tile(np.eye(2), (2, 1, 1))).shape == (2, 0)


def test_gate_probability_chi_square():
    assert abs(gate_probability(16.0, 2) - (1 - np.exp(-8))) <= 1e-15
    assert round(gate_probability(16.0, 2), 5) == 0.99966  # thesis implementation invariant 8
    assert abs(gate_probability(9.0, 3) - chi2.cdf(9.0, 3)) <= 1e-14


def test_shape_mismatch_is_a_clear_error():
    with pytest.raises(ValueError, match="S must be"):
        mahalanobis2(np.zeros((2, 3, 2)), np.zeros((3, 2, 2)))
