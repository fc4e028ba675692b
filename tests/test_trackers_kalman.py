"""Kalman filter in PDA form: closed forms, empty update, covariance hygiene, NEES/NIS consistency, errors."""

import numpy as np
import pytest
from scipy.stats import chi2

from roadtrack.trackers import FilterError, FilterState, cv_noise_gain, cv_process_noise, cv_transition, make_filter
from roadtrack.trackers.initiation import single_point, two_point
from roadtrack.trackers.models import PositionMeasurement
from roadtrack.trackers.gating import mahalanobis2

SIGMA_V, SIGMA_W, DT = 2.0, 0.3, 0.1


def random_state(rng, n=4):
    L = rng.normal(size=(n, n))
    return FilterState(x=rng.normal(size=n) * 10, P=L @ L.T + 0.1 * np.eye(n))


def test_ncv_model_matches_per_axis_closed_form():
    dt, q = 0.37, 1.7
    A = cv_transition(dt)
    Q = cv_process_noise(dt, q)
    per_axis = q**2 * np.array([[dt**4 / 4, dt**3 / 2], [dt**3 / 2, dt**2]])  # thesis §1.1
    for i in (0, 1):
        idx = np.ix_([i, i + 2], [i, i + 2])
        np.testing.assert_allclose(Q[idx], per_axis, rtol=0, atol=1e-15)
        np.testing.assert_allclose(A[idx], [[1, dt], [0, 1]], rtol=0, atol=0)
    np.testing.assert_allclose(Q[0, 1], 0.0, atol=0)
    np.testing.assert_allclose(cv_noise_gain(dt)[:, 0], [dt**2 / 2, 0, dt, 0], atol=1e-15)


def test_predict_equals_closed_form():
    rng = np.random.default_rng(1)
    kf = make_filter("kf", sigma_v=SIGMA_V, sigma_w=SIGMA_W)
    s = random_state(rng)
    p = kf.predict(s, DT)
    A = np.array([[1, 0, DT, 0], [0, 1, 0, DT], [0, 0, 1, 0], [0, 0, 0, 1.0]])
    G = np.array([[DT**2 / 2, 0], [0, DT**2 / 2], [DT, 0], [0, DT]])
    np.testing.assert_allclose(p.x, A @ s.x, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(p.P, A @ s.P @ A.T + G @ (SIGMA_V**2 * np.eye(2)) @ G.T, rtol=1e-12, atol=1e-12)


def test_single_measurement_update_is_standard_kf_joseph_form():
    rng = np.random.default_rng(2)
    kf = make_filter("kf", sigma_v=SIGMA_V, sigma_w=SIGMA_W)
    sp = kf.predict(random_state(rng), DT)
    z = sp.x[:2] + rng.normal(size=2)
    H = np.hstack([np.eye(2), np.zeros((2, 2))])
    R = SIGMA_W**2 * np.eye(2)
    S = H @ sp.P @ H.T + R
    K = sp.P @ H.T @ np.linalg.inv(S)
    x_ref = sp.x + K @ (z - H @ sp.x)
    P_ref = (np.eye(4) - K @ H) @ sp.P @ (np.eye(4) - K @ H).T + K @ R @ K.T
    z_hat, S_f = kf.predicted_measurement(sp)
    u = kf.update(sp, (z - z_hat)[None], np.array([1.0]), 0.0)
    np.testing.assert_allclose(S_f, S, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(u.x, x_ref, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(u.P, P_ref, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(u.P, (np.eye(4) - K @ H) @ sp.P, rtol=1e-9, atol=1e-12)  # optimal gain: short form too
    np.testing.assert_allclose(u.e_post, z - H @ x_ref, rtol=1e-12, atol=1e-12)  # (3.65)


def test_pda_update_equals_thesis_4_15_to_4_17():
    rng = np.random.default_rng(3)
    kf = make_filter("kf", sigma_v=SIGMA_V, sigma_w=SIGMA_W)
    sp = kf.predict(random_state(rng), DT)
    nu = rng.normal(size=(4, 2))
    beta = np.array([0.3, 0.1, 0.25, 0.05])
    beta0 = 1.0 - beta.sum()
    H = np.hstack([np.eye(2), np.zeros((2, 2))])
    R = SIGMA_W**2 * np.eye(2)
    K = sp.P @ H.T @ np.linalg.inv(H @ sp.P @ H.T + R)
    nu_c = sum(b * n for b, n in zip(beta, nu))
    P_star = (np.eye(4) - K @ H) @ sp.P @ (np.eye(4) - K @ H).T + K @ R @ K.T
    P_tilde = K @ (sum(b * np.outer(n, n) for b, n in zip(beta, nu)) - np.outer(nu_c, nu_c)) @ K.T
    u = kf.update(sp, nu, beta, beta0)
    np.testing.assert_allclose(u.x, sp.x + K @ nu_c, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(u.P, beta0 * sp.P + (1 - beta0) * P_star + P_tilde, rtol=1e-12, atol=1e-12)


def test_empty_or_missed_update_returns_the_prediction():
    rng = np.random.default_rng(4)
    kf = make_filter("kf", sigma_v=SIGMA_V, sigma_w=SIGMA_W)
    sp = kf.predict(random_state(rng), DT)
    assert kf.update(sp, np.zeros((0, 2)), np.zeros(0), 1.0) is sp
    u = kf.update(sp, rng.normal(size=(2, 2)), np.zeros(2), 1.0)
    assert u is sp
    np.testing.assert_array_equal(u.P, sp.P)


def test_covariance_symmetric_psd_after_many_steps():
    rng = np.random.default_rng(5)
    kf = make_filter("kf", sigma_v=SIGMA_V, sigma_w=SIGMA_W)
    s = kf.initial_state(*single_point(np.array([1.0, 2.0]), kf.measurement, 40.0))
    min_eig = np.inf
    for _ in range(300):
        s = kf.predict(s, rng.uniform(0.01, 0.5))
        M = rng.integers(0, 4)
        w = rng.dirichlet(np.ones(M + 1))
        s = kf.update(s, rng.normal(size=(M, 2)), w[1:], w[0])
        assert np.array_equal(s.P, s.P.T)
        min_eig = min(min_eig, np.linalg.eigvalsh(s.P)[0])
    assert min_eig > 1e-6


def test_nees_and_nis_within_chi_square_bounds():
    """100 seeded runs x 50 steps of NCV truth; per-step average NEES (4 dof) and NIS (2 dof) inside the
    two-sided 95% chi-square band at >= 90% of steps (expected 95%), overall means within 5% of 4 and 2."""
    runs, steps, dt = 100, 50, 0.1
    kf = make_filter("kf", sigma_v=SIGMA_V, sigma_w=SIGMA_W)
    rng = np.random.default_rng(20240601)
    A, Q = cv_transition(dt), cv_process_noise(dt, SIGMA_V)
    LQ = np.linalg.cholesky(Q + 1e-18 * np.eye(4))
    P0 = np.diag([SIGMA_W**2, SIGMA_W**2, 25.0, 25.0])
    nees = np.empty((runs, steps))
    nis = np.empty((runs, steps))
    for r in range(runs):
        x = np.array([0.0, 0.0, 25.0, 0.0])
        s = FilterState(x=x + np.linalg.cholesky(P0) @ rng.normal(size=4), P=P0)
        for k in range(steps):
            x = A @ x + LQ @ rng.normal(size=4)
            z = x[:2] + SIGMA_W * rng.normal(size=2)
            s = kf.predict(s, dt)
            z_hat, S = kf.predicted_measurement(s)
            nis[r, k] = mahalanobis2((z - z_hat)[None, None], S[None])[0, 0]
            s = kf.update(s, (z - z_hat)[None], np.array([1.0]), 0.0)
            e = x - s.x
            nees[r, k] = e @ np.linalg.solve(s.P, e)
    for vals, dof in ((nees, 4), (nis, 2)):
        lo, hi = chi2.ppf([0.025, 0.975], dof * runs) / runs
        inside = np.mean((vals.mean(0) >= lo) & (vals.mean(0) <= hi))
        assert inside >= 0.90, (dof, inside)
        assert abs(vals.mean() - dof) <= 0.05 * dof, (dof, vals.mean())


def test_initiate_matches_section_7_2():
    kf = make_filter("kf", sigma_v=SIGMA_V, sigma_w=SIGMA_W)
    s = kf.initial_state(*single_point(np.array([3.0, -4.0]), kf.measurement, 40.0))
    np.testing.assert_allclose(s.x, [3.0, -4.0, 0.0, 0.0], atol=0)
    np.testing.assert_allclose(s.P, np.diag([0.09, 0.09, 1600 / 3, 1600 / 3]), rtol=1e-15)
    np.testing.assert_allclose(s.e_post, [0.0, 0.0], atol=0)
    x0, P0 = two_point(np.array([1.0, 2.0]), np.array([3.5, 2.0]), 0.1, PositionMeasurement(0.3))
    np.testing.assert_allclose(x0, [3.5, 2.0, 25.0, 0.0], rtol=1e-12)
    R = 0.09 * np.eye(2)
    np.testing.assert_allclose(P0, np.block([[R, R / 0.1], [R / 0.1, 2 * R / 0.01]]), rtol=1e-12)
    ct = make_filter("ekf", motion="ct", sigma_v=SIGMA_V, sigma_w=SIGMA_W, omega_std0=0.2)
    s5 = ct.initial_state(x0, P0)  # the CT model appends omega = 0 with variance omega_std0^2
    np.testing.assert_allclose(s5.x, [3.5, 2.0, 25.0, 0.0, 0.0], rtol=1e-12)
    assert s5.P[4, 4] == pytest.approx(0.04) and np.all(s5.P[4, :4] == 0)


def test_singular_or_nonfinite_covariance_gives_one_line_filter_error():
    kf = make_filter("kf", sigma_v=SIGMA_V, sigma_w=SIGMA_W)
    singular = FilterState(x=np.zeros(4), P=np.diag([-0.09, 1.0, 1.0, 1.0]))  # S = H P H^T + R has a zero eigenvalue
    with pytest.raises(FilterError, match="not positive definite") as e:
        kf.update(singular, np.ones((1, 2)), np.array([1.0]), 0.0)
    assert "\n" not in str(e.value)
    with pytest.raises(FilterError, match="not positive definite"):
        mahalanobis2(np.ones((1, 1, 2)), np.zeros((1, 2, 2)))
    nan_state = FilterState(x=np.zeros(4), P=np.full((4, 4), np.nan))
    with pytest.raises(FilterError, match="not finite") as e:
        kf.predict(nan_state, 0.1)
    assert "\n" not in str(e.value)
    assert issubclass(FilterError, ValueError)


def test_state_is_an_immutable_value_and_inputs_are_checked():
    x = np.zeros(4)
    s = FilterState(x=x, P=np.eye(4))
    x[0] = 5.0
    assert s.x[0] == 0.0  # the state owns a copy
    with pytest.raises(ValueError):
        s.x[0] = 1.0
    np.testing.assert_array_equal(s.e_post, np.zeros(2))
    with pytest.raises(ValueError, match="P must be"):
        FilterState(x=np.zeros(4), P=np.eye(3))
    kf = make_filter("kf", sigma_v=SIGMA_V, sigma_w=SIGMA_W)
    with pytest.raises(ValueError, match="sum to 1"):
        kf.update(s, np.ones((1, 2)), np.array([0.5]), 0.2)
    with pytest.raises(ValueError, match="dt"):
        kf.predict(s, -0.1)
    with pytest.raises(ValueError, match="filter.sigma_w: 0.0 is not allowed; must be > 0"):
        make_filter("kf", sigma_v=1.0, sigma_w=0.0)
    with pytest.raises(ValueError, match="filter.motion: 'ct' is nonlinear"):
        make_filter("kf", motion="ct")
