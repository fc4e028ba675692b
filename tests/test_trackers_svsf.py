"""SVSF family (standard, generalised / CM, GVBL): closed forms, thesis identities, covariance hygiene,
robustness to model error, and the thesis's simulation claims (§2.1, §4.6.1) on the seeded synthetic harness.

Slow variants (1e5 steps, 100-run Monte Carlo) are marked slow and run with ROADTRACK_FULL=1; each has a
reduced unmarked version. Claims tests: where a published claim does not come out
with the stated parameters, the test asserts what does happen (the numbers are in the assertions and docstrings)."""

import math
import os
from dataclasses import replace

import numpy as np
import pytest

from roadtrack.testbed.reproduce.thesis import synthetic as sy
from roadtrack.trackers import make_tracker
from roadtrack.trackers.filters import FILTERS, KalmanFilter, make_filter
from roadtrack.trackers.filters.gvbl import GVBLSVSF
from roadtrack.trackers.filters.kalman import ExtendedKalmanFilter
from roadtrack.trackers.filters.svsf import GeneralisedSVSF, generalised_covariance
from roadtrack.trackers.models import ConstantVelocity, CoordinatedTurn, PositionMeasurement
from roadtrack.trackers.params import ParamError
from roadtrack.trackers.state import FilterState

FULL = bool(os.environ.get("ROADTRACK_FULL"))  # run the slow Monte Carlo variants (as tests/test_trackers_filters)
SV, SW, DT = 0.5, 3.0, 0.5  # thesis §4.6.1: sigma_v^2 = 0.5^2, sigma_w^2 = 3^2; Ts = 0.5 s ([I]: inferred from the thesis's numbers)
H = np.hstack([np.eye(2), np.zeros((2, 2))])
R = SW ** 2 * np.eye(2)


def cv():
    return ConstantVelocity(SV), PositionMeasurement(SW)


def svsf_filters():
    """Every SVSF-family filter this module tests: (name, filter)."""
    ct = CoordinatedTurn(SV)
    return [("svsf", make_filter("svsf", sigma_v=SV, sigma_w=SW)),
            ("svsf-pinv", make_filter("svsf", sigma_v=SV, sigma_w=SW, unmeasured="pinv")),
            ("gc-svsf", make_filter("gc-svsf", sigma_v=SV, sigma_w=SW)),
            ("gvbl-svsf", make_filter("gvbl-svsf", sigma_v=SV, sigma_w=SW)),
            ("gvbl-svsf-ct", make_filter("gvbl-svsf", motion="ct", sigma_v=SV, sigma_w=SW))]


def predicted(flt, rng, x=(10.0, -5.0, 20.0, 3.0), e_post=(0.0, 0.0)):
    s = flt.initial_state(np.array(x), np.diag([4.0, 4.0, 9.0, 9.0]))
    s = flt.predict(flt.update(flt.predict(s, DT), rng.normal(size=(1, 2)) * SW, np.ones(1), 0.0), DT)
    return s


def pda_inputs(rng, M=3):
    nu = rng.normal(size=(M, 2)) * SW
    beta = rng.dirichlet(np.ones(M + 1))
    return nu, beta[1:], float(beta[0])


# ------------------------------------------------------------------------------------------ contract
def test_registry_names_and_params():
    for name in ("svsf", "gc-svsf", "gvbl-svsf"):
        assert name in FILTERS
    assert make_filter("svsf", sigma_w=2.0).psi == (6.0, 6.0)  # default layer 3 sigma_w [D]
    assert make_filter("gvbl-svsf", psi_max=None).psi_max == math.inf
    with pytest.raises(ParamError, match="filter.motion: 'ct': the standard SVSF"):
        make_filter("svsf", motion="ct")
    with pytest.raises(ParamError, match="filter.motion: 'ct': the generalised SVSF needs Phi12 invertible"):
        make_filter("gc-svsf", motion="ct")
    with pytest.raises(ParamError, match="filter.robust_lower: 'psi_max' needs Phi12 invertible"):
        make_filter("gvbl-svsf", motion="ct", robust_lower="psi_max")
    with pytest.raises(ParamError, match=r"filter.gamma: 1.0 is not allowed; must be in \[0, 1\)"):
        make_filter("gvbl-svsf", gamma=1.0)
    with pytest.raises(ParamError, match="filter.switch"):
        make_filter("gvbl-svsf", switch="sometimes")


def test_make_tracker_routes_svsf_keys_and_steps():
    trk = make_tracker("jpda-gvbl-svsf", sigma_v=4.0, sigma_w=0.5, gamma=0.1, psi_max=2.0)
    assert isinstance(trk.filter, GVBLSVSF) and trk.filter.psi_max == 2.0 and trk.filter.gamma == 0.1
    res = trk.step((), np.array([[0.0, 0.0], [30.0, 5.0]]), 0.1, 0)
    res = trk.step(res.tracks, np.array([[0.1, 0.0], [30.0, 5.2]]), 0.1, res.next_id)
    assert len(res.tracks) >= 2
    np.testing.assert_allclose(res.info.layers[~np.isnan(res.info.layers)], 2.0, rtol=0, atol=0)  # psi_max first
    for name in ("pda-svsf", "gnn-gc-svsf", "pda-gvbl-svsf"):
        trk, tracks, nid = make_tracker(name, sigma_v=2.0, sigma_w=0.3), (), 0
        for k in range(6):
            res = trk.step(tracks, np.array([[0.5 * k, 0.0], [30.0, 0.2 * k]]), 0.1, nid)
            tracks, nid = res.tracks, res.next_id
        assert "psi_z_0" in res.info.diagnostics and np.isfinite(res.info.layers).all(), name


@pytest.mark.parametrize("name,flt", svsf_filters(), ids=lambda v: v if isinstance(v, str) else "")
def test_empty_or_missed_update_returns_the_prediction(name, flt):
    sp = predicted(flt, np.random.default_rng(1))
    assert flt.update(sp, np.zeros((0, 2)), np.zeros(0), 1.0) is sp
    assert flt.update(sp, np.ones((1, 2)), np.zeros(1), 1.0) is sp
    with pytest.raises(ValueError, match="sum to 1"):
        flt.update(sp, np.ones((1, 2)), np.array([0.5]), 0.2)


@pytest.mark.parametrize("name,flt", svsf_filters(), ids=lambda v: v if isinstance(v, str) else "")
def test_e_post_is_3_65_and_pda_covariance(name, flt):
    """e_{z,k|k} = (I - H K) e_{z,k|k-1} (3.65), with K e = x_post - x_pred; P symmetric PSD."""
    rng = np.random.default_rng(2)
    sp = predicted(flt, rng)
    nu, beta, beta0 = pda_inputs(rng)
    u = flt.update(sp, nu, beta, beta0)
    nu_c = beta @ nu
    Hn = np.eye(2, len(sp.x))
    np.testing.assert_allclose(u.e_post, nu_c - Hn @ (u.x - sp.x), rtol=0, atol=1e-12)
    np.testing.assert_array_equal(u.P, u.P.T)
    assert np.linalg.eigvalsh(u.P)[0] > 0


def test_update_without_predict_is_a_one_line_error():
    flt = make_filter("gc-svsf", sigma_v=SV, sigma_w=SW)
    s = flt.initial_state(np.zeros(4), np.eye(4))
    with pytest.raises(ValueError, match="needs s_pred.F"):
        flt.update(s, np.ones((1, 2)), np.ones(1), 0.0)


# ------------------------------------------------------------------------------------------ closed forms
def test_generalised_covariance_equals_joseph_form():
    """(4.37) with S = H1 P11 H1^T + R is the Joseph form for ANY gain K (thesis §3.3 identity)."""
    rng = np.random.default_rng(3)
    for n in (4, 5):
        L = rng.normal(size=(n, n))
        P = L @ L.T + np.eye(n)
        Hn = np.eye(2, n)
        K = rng.normal(size=(n, 2))
        S = Hn @ P @ Hn.T + R
        I_KH = np.eye(n) - K @ Hn
        np.testing.assert_allclose(generalised_covariance(P, K, Hn, S), I_KH @ P @ I_KH.T + K @ R @ K.T,
                                   rtol=1e-12, atol=1e-10)


def test_gc_svsf_update_matches_ncv_closed_form():
    """Reference §3.2 NCV specialisation: K_u,jj = E_z,j / max(|e_j|, psi_z), E_y = (1 + gamma)|e| / Ts,
    K_l,jj = E_y,j / max(|e_j| / Ts, psi_y) / Ts; P* by (4.37); PDA combination (4.16)-(4.17)."""
    rng = np.random.default_rng(4)
    g, psi_z, psi_y = 0.1, 4.0, 7.0
    flt = GeneralisedSVSF(*cv(), gamma=g, gamma_y=g, psi_z=(psi_z, psi_z), psi_y=psi_y, covariance="joseph")
    sp = predicted(flt, rng)
    e_prev = sp.e_post
    nu, beta, beta0 = pda_inputs(rng)
    e = beta @ nu
    Ku = np.diag((np.abs(e) + g * np.abs(e_prev)) / np.maximum(np.abs(e), psi_z))
    Kl = np.diag((1 + g) * np.abs(e) / DT / np.maximum(np.abs(e) / DT, psi_y) / DT)
    K = np.vstack([Ku, Kl])
    S = H @ sp.P @ H.T + R
    I_KH = np.eye(4) - K @ H
    P_star = I_KH @ sp.P @ I_KH.T + K @ R @ K.T
    spread = sum(b * np.outer(n, n) for b, n in zip(beta, nu)) - np.outer(e, e)
    u = flt.update(sp, nu, beta, beta0)
    np.testing.assert_allclose(u.x, sp.x + K @ e, rtol=0, atol=1e-12)
    np.testing.assert_allclose(u.P, beta0 * sp.P + (1 - beta0) * P_star + K @ spread @ K.T, rtol=1e-12, atol=1e-12)
    assert S.shape == (2, 2)


def test_svsf_artificial_update_matches_closed_form():
    """Standard SVSF with the artificial velocity measurement of [17] (thesis §4.5.1): H_bar = I, R_bar, and
    K = diag(E o sat(e, psi)) diag(e)^-1 (2.30) on z_bar = [z; (z - z_prev)/tau]; Joseph P* (2.31)."""
    rng = np.random.default_rng(5)
    flt = make_filter("svsf", sigma_v=SV, sigma_w=SW, gamma=0.2, psi=5.0, psi_v=4.0, covariance="joseph")
    s0 = flt.initial_state(np.array([0.0, 0.0, 10.0, 2.0]), np.diag([9.0, 9.0, 4.0, 4.0]))
    s1 = flt.update(flt.predict(s0, DT), np.array([[1.0, -2.0]]), np.ones(1), 0.0)  # first update: positions only
    np.testing.assert_array_equal(s1.x[2:], s0.x[2:])
    assert s1.tau == 0.0
    np.testing.assert_allclose(s1.z_prev, [5.0 + 1.0, 1.0 - 2.0], atol=1e-12)  # (2.32) projected measurement
    sp = flt.predict(flt.predict(s1, DT), DT)  # a missed scan in between: tau = 2 Ts
    assert sp.tau == pytest.approx(2 * DT, abs=1e-15)
    nu, beta, beta0 = pda_inputs(rng, 2)
    tau = 2 * DT
    z_hat = sp.x[:2]
    nub = np.hstack([nu, (z_hat + nu - s1.z_prev) / tau - sp.x[2:]])
    e = beta @ nub
    E = np.abs(e) + 0.2 * np.abs(np.r_[s1.e_post, s1.e_vel])
    K = np.diag(E / np.maximum(np.abs(e), [5.0, 5.0, 4.0, 4.0]))
    Rb = np.block([[R, R / tau], [R / tau, 2 * R / tau ** 2]])
    P_star = (np.eye(4) - K) @ sp.P @ (np.eye(4) - K).T + K @ Rb @ K.T
    spread = sum(b * np.outer(n, n) for b, n in zip(beta, nub)) - np.outer(e, e)
    u = flt.update(sp, nu, beta, beta0)
    np.testing.assert_allclose(u.x, sp.x + K @ e, rtol=0, atol=1e-12)
    np.testing.assert_allclose(u.P, beta0 * sp.P + (1 - beta0) * P_star + K @ spread @ K.T, rtol=1e-12, atol=1e-10)
    np.testing.assert_allclose(np.r_[u.e_post, u.e_vel], e - K @ e, rtol=0, atol=1e-12)  # (2.34) in z_bar space


def test_svsf_literal_pinv_form_never_corrects_velocity_and_short_covariance():
    """(2.30) with H^+ = H^T: velocity rows of K are zero (thesis (2.10) with H^+ = H^T); covariance="short" is (I - K H) P."""
    rng = np.random.default_rng(6)
    flt = make_filter("svsf", sigma_v=SV, sigma_w=SW, unmeasured="pinv", covariance="short", psi=4.0)
    sp = predicted(flt, rng)
    nu = np.array([[7.0, -1.0]])
    u = flt.update(sp, nu, np.ones(1), 0.0)
    np.testing.assert_array_equal(u.x[2:], sp.x[2:])
    E = np.abs(nu[0]) + 0.1 * np.abs(sp.e_post)
    K = H.T @ np.diag(E / np.maximum(np.abs(nu[0]), 4.0))
    np.testing.assert_allclose(u.P, 0.5 * ((np.eye(4) - K @ H) @ sp.P + ((np.eye(4) - K @ H) @ sp.P).T),
                               rtol=1e-12, atol=1e-12)


def test_gamma_contraction_when_saturated():
    """Thesis §2.3: with the error outside the layer, e_{k|k} = -gamma |e_{k-1|k-1}| sign(e_{k|k-1}), so
    |e_{k|k}| = gamma |e_{k-1|k-1}| component-wise: all four components of the artificial-measurement SVSF
    (H_bar = I), the measured partition of the generalised SVSF and of the GVBL-SVSF's robust regime."""
    g = 0.3
    e_prev = np.array([2.0, -3.0])
    nu = np.array([[40.0, -55.0]])
    svsf = make_filter("svsf", sigma_v=SV, sigma_w=SW, gamma=g, psi=1e-3, psi_v=1e-3)
    s = svsf.predict(svsf.initial_state(np.zeros(4), np.eye(4)), DT)
    s = svsf.update(s, nu, np.ones(1), 0.0)  # stores z_prev
    for _ in range(3):
        sp = svsf.predict(s, DT)
        prev = np.r_[sp.e_post, sp.e_vel]
        u = svsf.update(sp, np.array([[25.0, -30.0]]), np.ones(1), 0.0)
        np.testing.assert_allclose(np.abs(np.r_[u.e_post, u.e_vel]), g * np.abs(prev), rtol=1e-12, atol=1e-12)
        s = u
    for flt in (GeneralisedSVSF(*cv(), gamma=g, psi_z=(1e-3, 1e-3)), GVBLSVSF(*cv(), gamma=g, psi_max=1e-3)):
        sp = flt.predict(FilterState(x=np.zeros(4), P=np.eye(4), e_post=e_prev), DT)
        u = flt.update(sp, nu, np.ones(1), 0.0)
        np.testing.assert_allclose(u.e_post, -g * np.abs(e_prev) * np.sign(nu[0]), rtol=1e-12, atol=1e-12)


# ------------------------------------------------------------------------------------------ GVBL = KF
def clutter_run(steps=200, seed=7):
    scn = sy.Scenario(x0=(0.0, 0.0, 20.0, 5.0), segments=(sy.Segment(steps // 2), *sy.curve(steps // 2 * DT, DT,
                      math.radians(60))), dt=DT, sigma_v=SV, sigma_w=SW, pd=0.9, clutter_density=1e-3)
    return scn, sy.simulate(scn, seed)


def test_gvbl_without_limit_is_the_kalman_filter_over_a_pda_run():
    """psi_max = inf: GVBL-SVSF reproduces PDA-KF to 1e-9 over 200 cluttered scans (thesis (4.73));
    the same for the 5-D CT model against the EKF."""
    scn, run = clutter_run()
    for kf, gv in ((KalmanFilter(*cv()), GVBLSVSF(*cv(), psi_max=math.inf)),
                   (ExtendedKalmanFilter(CoordinatedTurn(SV), PositionMeasurement(SW)),
                    make_filter("gvbl-svsf", motion="ct", sigma_v=SV, sigma_w=SW, psi_max=None))):
        a, b = sy.track(run, scn, kf), sy.track(run, scn, gv)
        np.testing.assert_allclose(b.x, a.x, rtol=0, atol=1e-9)
        np.testing.assert_allclose(b.P, a.P, rtol=0, atol=1e-9)
        assert np.all(b.info["regime"][~np.isnan(b.info["regime"])] == 0.0)
        assert b.n_gated.sum() > 250  # clutter was in the gates: the PDA weights were exercised


def test_gvbl_optimal_regime_is_the_kalman_update_and_switch_rate():
    """psi_max = 20 m (thesis ch. 4): every scan in the optimal regime is the KF update from the same prior
    to 1e-9; robust scans differ. On this run (a 60 deg turn, clutter 1e-3 /m^2) the switch rate is measured."""
    scn, run = clutter_run()
    gv, kf = GVBLSVSF(*cv()), KalmanFilter(*cv())
    s = gv.initial_state(run.x0_est, run.P0)
    robust = []
    for Z in run.Z:
        sp = gv.predict(s, DT)
        z_hat, _ = gv.predicted_measurement(sp)
        nu = Z - z_hat
        d2 = np.einsum("mi,ij,mj->m", nu, np.linalg.inv(sp.P[:2, :2] + R), nu)
        nu = nu[d2 <= 16.0]
        if len(nu) == 0:
            s = sp
            continue
        beta = np.full(len(nu), 1.0 / (len(nu) + 1))
        s = gv.update(sp, nu, beta, 1.0 / (len(nu) + 1))
        k = kf.update(sp, nu, beta, 1.0 / (len(nu) + 1))
        robust.append(s.info["regime"])
        if s.info["regime"] == 0.0:
            np.testing.assert_allclose(s.x, k.x, rtol=0, atol=1e-9)
            np.testing.assert_allclose(s.P, k.P, rtol=0, atol=1e-9)
        else:
            assert np.abs(s.x - k.x).max() > 1e-6
    rate = float(np.mean(robust))
    assert 0.02 < rate < 0.5, rate


def test_layers_reported_to_association():
    """svsf / gc-svsf: the fixed layer; gvbl: psi_max before the first update, then min(|diag Psi_z|, psi_max)
    of the previous update; None without a limit before the first update."""
    rng = np.random.default_rng(8)
    np.testing.assert_array_equal(make_filter("svsf", sigma_w=2.0).layer(None), [6.0, 6.0])
    np.testing.assert_array_equal(make_filter("gc-svsf", psi_z=1.5).layer(None), [1.5, 1.5])
    gv = GVBLSVSF(*cv(), psi_max=5.0)
    s = gv.predict(gv.initial_state(np.zeros(4), np.eye(4)), DT)
    np.testing.assert_array_equal(gv.layer(s), [5.0, 5.0])
    u_nu = rng.normal(size=(2, 2)) * 20.0
    u = gv.update(s, u_nu, np.array([0.5, 0.3]), 0.2)
    np.testing.assert_allclose(gv.layer(gv.predict(u, DT)), np.minimum(u.info["psi_z"], 5.0), rtol=0, atol=0)
    nu_c = np.array([0.5, 0.3]) @ u_nu
    np.testing.assert_allclose(u.info["chatter"], np.maximum(0.0, np.abs(nu_c) - np.minimum(u.info["psi_z"], 5.0)),
                               rtol=0, atol=1e-15)  # (5.37) against the effective layer
    assert GVBLSVSF(*cv(), psi_max=math.inf).layer(s) is None


# ------------------------------------------------------------------------------------------ hygiene
def long_run(flt, steps, seed=9):
    """predict/update with a turning target measured every scan (and a miss every 7th); returns worst
    relative eigenvalue and asymmetry seen."""
    rng = np.random.default_rng(seed)
    A = CoordinatedTurn(0.0).transition(DT, 0.05)[:4, :4]
    x = np.array([0.0, 0.0, 15.0, 0.0])
    s = flt.initial_state(x, np.diag([9.0, 9.0, 4.0, 4.0]))
    worst, asym = np.inf, 0.0
    for k in range(steps):
        x = A @ x
        sp = flt.predict(s, DT)
        if k % 7 == 6:
            s = flt.update(sp, np.zeros((0, 2)), np.zeros(0), 1.0)
            continue
        z_hat, _ = flt.predicted_measurement(sp)
        nu = np.vstack([x[:2] + rng.normal(size=2) * SW - z_hat, rng.normal(size=2) * 3 * SW])
        s = flt.update(sp, nu, np.array([0.7, 0.1]), 0.2)
        w = np.linalg.eigvalsh(s.P)
        worst = min(worst, w[0] / w[-1])
        asym = max(asym, np.abs(s.P - s.P.T).max())
    return worst, asym, s


@pytest.mark.parametrize("name,flt", svsf_filters(), ids=lambda v: v if isinstance(v, str) else "")
def test_covariance_symmetric_psd_reduced(name, flt):
    worst, asym, s = long_run(flt, 1_000)
    assert asym == 0.0 and worst > 0.0 and np.isfinite(s.x).all()


@pytest.mark.slow
@pytest.mark.skipif(not FULL, reason="full 1e5-step run: set ROADTRACK_FULL=1")
@pytest.mark.parametrize("name,flt", svsf_filters(), ids=lambda v: v if isinstance(v, str) else "")
def test_covariance_symmetric_psd_after_1e5_steps(name, flt):
    worst, asym, s = long_run(flt, 100_000)
    assert asym == 0.0 and worst > 0.0 and np.isfinite(s.x).all()


def test_svsf_family_stays_bounded_under_model_error_where_the_kf_diverges():
    """Truth x_{k+1} = 1.01 A x_k for 300 s (a persistent 1 % error in the transition, thesis §2.1.6 style);
    every scan measured, no association. The KF (sigma_v = 0.01) error grows with the state (885 m at the
    end); every SVSF-family filter stays within a few sigma_w (<= 3.6 m for sigma_w = 1 m)."""
    rng = np.random.default_rng(5)
    A = 1.01 * ConstantVelocity(0).transition(1.0)
    X = [np.array([100.0, 100.0, 10.0, 5.0])]
    for _ in range(300):
        X.append(A @ X[-1])
    X = np.array(X)
    Z = X[1:, :2] + rng.normal(size=(300, 2))
    final = {}
    for name in ("kf", "svsf", "gc-svsf", "gvbl-svsf"):
        f = make_filter(name, sigma_v=0.01, sigma_w=1.0)
        s = f.initial_state(X[0], np.eye(4))
        err = []
        for k in range(300):
            sp = f.predict(s, 1.0)
            s = f.update(sp, (Z[k] - f.predicted_measurement(sp)[0])[None], np.ones(1), 0.0)
            err.append(np.hypot(*(s.x[:2] - X[k + 1, :2])))
        final[name] = (err[-1], max(err[-100:]))
    assert final["kf"][0] > 500.0
    for name in ("svsf", "gc-svsf", "gvbl-svsf"):
        assert final[name][1] < 4.0, (name, final[name])


# ------------------------------------------------------------------------------------------ thesis claims
# §2.1 (thesis §2.1.6, Tables 2.2-2.3): Ts = 30 s, sigma_v^2 = 0.01^2, sigma_w^2 = 7^2, P_D = 0.9, lambda = 1e-6.
# Unstated, chosen here [D]: x0 = (0 m, 0 m, 10 m/s, 5 m/s), 100 scans, the model error "2 % change in the
# system matrix for 5 iterations" as a_scale = 1.02 (resp. 1.04) on scans 26-30 ([R]: thesis §2.1.6 prints no more),
# gate alpha = 16, known initial state with P0 = diag(R, 2R/Ts^2), "lost" = position error > 10 sigma_w
# = 70 m for the last >= 5 scans.
S21_SV, S21_SW, S21_TS = 0.01, 7.0, 30.0


def s21(eps):
    return sy.Scenario(x0=(0.0, 0.0, 10.0, 5.0), segments=(sy.Segment(25), sy.Segment(5, a_scale=1 + eps),
                       sy.Segment(70)), dt=S21_TS, sigma_v=S21_SV, sigma_w=S21_SW, pd=0.9, clutter_density=1e-6)


def s21_filters():
    return {"kf": make_filter("kf", sigma_v=S21_SV, sigma_w=S21_SW),
            "svsf": make_filter("svsf", sigma_v=S21_SV, sigma_w=S21_SW, covariance="joseph"),  # (2.31) as printed
            # the literal ch. 2 form: sign(e / psi) of (2.10) (psi -> 0) and C^+ of (2.10)/(2.30)
            "literal": make_filter("svsf", sigma_v=S21_SV, sigma_w=S21_SW, psi=1e-6, unmeasured="pinv",
                                   covariance="joseph")}


def s21_results(n_runs, seed):
    return {eps: sy.monte_carlo(s21(eps), s21_filters(), n_runs, seed) for eps in (0.0, 0.02, 0.04)}


def test_claim_s21_pda_svsf_vs_pda_kf_reduced():
    """Thesis §2.1: SVSF-PDA better than KF-PDA in the normal case (x 64.5 vs 92.4 m), far better under a 2 %
    model error (x 125.1 vs 721.7 m, y 207.3 vs 284.3 m), and at 4 % the KF-PDA loses the target while the
    SVSF-PDA keeps it. The claim does NOT come out. Measured, 10 runs (seed 2101) / 100 runs (seed 2100, slow):
    * normal: default SVSF (artificial velocity, psi = 3 sigma_w) worse than the KF: x 9.8 vs 8.2 m /
      19.0 vs 8.2 m; the literal ch. 2 gain (sign of (2.10), i.e. psi -> 0, with C^+) 36.7 / 23.9 m;
    * 2 %: KF x 788 / 820 m, default SVSF 1343 / 1057 m, literal 491 / 1252 m; lost 0, 1, 0 / 1, 12, 6;
    * 4 %: lost KF 4/10 / 43/100, default SVSF 7/10 / 86/100, literal 2/10 / 34/100.
    The KF does lose the target at 4 % in a large fraction of runs; every SVSF form loses it too, the default
    one about twice as often (its artificial velocity takes the injected position jumps as velocity)."""
    res = s21_results(10, 2101)
    kf0, sv0 = res[0.0]["kf"].rmse(), res[0.0]["svsf"].rmse()
    assert 1.0 < sv0[0] / kf0[0] < 1.5 and 1.0 < sv0[1] / kf0[1] < 1.8  # normal: SVSF worse (thesis: better)
    assert res[0.02]["svsf"].rmse()[0] > 1.3 * res[0.02]["kf"].rmse()[0]  # 2 %: no gain (measured 1.70x)
    lost4 = {k: int(r.lost(10 * S21_SW).sum()) for k, r in res[0.04].items()}
    assert lost4 == {"kf": 4, "svsf": 7, "literal": 2}, lost4


@pytest.mark.slow
@pytest.mark.skipif(not FULL, reason="100-run Monte Carlo: set ROADTRACK_FULL=1")
def test_claim_s21_pda_svsf_vs_pda_kf_100_runs():
    """As the reduced test over 100 runs (seed 2100), numbers in its docstring (about 80 s)."""
    res = s21_results(100, 2100)
    kf2 = res[0.02]["kf"].rmse()
    assert res[0.02]["svsf"].rmse()[0] > 1.2 * kf2[0] and res[0.02]["literal"].rmse()[0] > 1.2 * kf2[0]
    lost4 = {k: int(r.lost(10 * S21_SW).sum()) for k, r in res[0.04].items()}
    assert 35 <= lost4["kf"] <= 50 and lost4["svsf"] >= 80 and 25 <= lost4["literal"] <= 40, lost4


# §4.6.1 (thesis Tables 4.1-4.2): Ts = 0.5 s [I], sigma_v^2 = 0.5^2, sigma_w^2 = 3^2, alpha = 16, P_D = 0.9,
# lambda = 1e-2, gamma = 0.1, psi_max = 20, NCV filters on manoeuvring cars. Chosen here [D]: the manoeuvre
# shapes [D] (curve: +10 deg heading change; cut-in-out: 3.5 m), truth process noise sigma_v in
# NCV segments, clutter in a +-30 m square around the car, JPDA of non-interfering cars = per-car PDA.
S41_CARS = {1: ((200.0, 50.0, 28.0, 1.0), ((93, "ncv"), (139, "curve"), (500, "ncv"))),
            2: ((-1000.0, 25.0, 33.0, 1.0), ((115, "ncv"), (156, "curve"), (241, "ncv"), (325, "cut_in_out"),
                                            (500, "ncv"))),
            3: ((-2000.0, 0.0, 34.0, 1.0), ((139, "ncv"), (179, "curve"), (367, "ncv"), (418, "cut_in_out"),
                                           (500, "ncv")))}


def s41(x0, spec, lam):
    return sy.Scenario(x0=x0, segments=sy.from_timeline(x0, DT, spec), dt=DT, sigma_v=SV, sigma_w=SW, pd=0.9,
                       clutter_density=lam)


def s41_filters():
    return {"kf": make_filter("kf", sigma_v=SV, sigma_w=SW), "gvbl": make_filter("gvbl-svsf", sigma_v=SV, sigma_w=SW),
            "gvbl-psi_max-lower": make_filter("gvbl-svsf", sigma_v=SV, sigma_w=SW, robust_lower="psi_max")}


def test_claim_s41_gvbl_vs_kf_reduced():
    """Thesis §4.6.1: JPDA-GVBL-SVSF RMSE <= JPDA-KF for every car and state, y improved by 22-42 %
    (Car 1: x 1.37 vs 1.43, y 0.70 vs 1.21 m). Reduced: Car 1 from t = 60 s to 200 s (its curve), 2 runs.
    Measured:
    * lambda = 1e-2 (as printed): about 6 clutter points per gate; the combined innovation is shrunk and P
      inflated, so |Psi_z| never exceeds psi_max: GVBL-SVSF is the KF exactly (max difference 5e-11 m) and
      both have RMSE x 7.6, y 10.2 m, far above the thesis's 1.43 / 1.21 (the printed clutter density is far denser than the thesis's results imply);
    * lambda = 1e-4 (the change that brings the KF to the thesis level, 1.64 / 2.04 m): GVBL switches on 21 %
      of the scans and is 1-3 % WORSE than the KF (x 1.68, y 2.05 m), also inside the curve;
    * robust_lower = "psi_max" (Psi_y = psi_max I in (4.40)) loses the target (x RMSE 382 m).
    The claim does not come out; no tested variation (heading change 10/45/90 deg, noise-free truth, any
    switch rule) made the GVBL-SVSF better than the KF (see the final report)."""
    x0 = (200.0 + 28.0 * 60, 50.0 + 60.0, 28.0, 1.0)
    spec = ((33, "ncv"), (79, "curve"), (140, "ncv"))
    dense = sy.monte_carlo(s41(x0, spec, 1e-2), s41_filters(), 2, 41)
    np.testing.assert_allclose(dense["gvbl"].errors, dense["kf"].errors, rtol=0, atol=1e-8)
    assert np.nansum(dense["gvbl"].info["regime"]) == 0.0
    assert np.all(dense["kf"].rmse()[:2] > 4.0 * np.array([1.43, 1.21]))
    sparse = {k: v for k, v in sy.monte_carlo(s41(x0, spec, 1e-4), s41_filters(), 2, 41).items()}
    kf, gv = sparse["kf"].rmse(), sparse["gvbl"].rmse()
    assert np.all(kf[:2] < 2.2)
    assert np.all(gv[:2] / kf[:2] > 1.0) and np.all(gv[:2] / kf[:2] < 1.05)  # slightly worse, never better
    assert 0.15 < np.nanmean(sparse["gvbl"].info["regime"]) < 0.3
    assert sparse["gvbl-psi_max-lower"].rmse()[0] > 50.0


@pytest.mark.slow
@pytest.mark.skipif(not FULL, reason="3 cars x 10 runs x 1000 scans: set ROADTRACK_FULL=1")
def test_claim_s41_gvbl_vs_kf_three_cars():
    """All three cars, full 500 s, 10 runs each, lambda = 1e-4 (see the reduced test): GVBL-SVSF within
    +-5 % of the KF on positions for every car, never better by more than 1 %."""
    for car, (x0, spec) in S41_CARS.items():
        mc = sy.monte_carlo(s41(x0, spec, 1e-4), {k: v for k, v in s41_filters().items() if k != "gvbl-psi_max-lower"},
                            10, 410 + car)
        ratio = mc["gvbl"].rmse()[:2] / mc["kf"].rmse()[:2]
        assert np.all(ratio > 0.99) and np.all(ratio < 1.05), (car, ratio)


# ---------------------------------------------------------------- batched paths against the per-track reference
BATCHED = [("svsf", {}), ("svsf", {"psi_v": 2.0}), ("svsf", {"gamma": 0.0, "psi": 0.2}),
           ("gvbl-svsf", {}), ("gvbl-svsf", {"psi_max": 0.5}), ("gvbl-svsf", {"psi_max": 0.5, "switch": "per_partition"}),
           ("gvbl-svsf", {"psi_max": 0.5, "switch": "all_any", "robust_lower": "psi_max"}),
           ("gvbl-svsf", {"psi_max": 0.5, "ey_memory": "a_posteriori"}),
           ("svsf", {"artificial_pda": "combined"}), ("svsf", {"memory_after_miss": "reset"}),
           ("gvbl-svsf", {"psi_max": 0.5, "memory_after_miss": "reset", "apda_layer": "psi_max"}),
           ("gc-svsf", {}), ("ekf", {}), ("kf", {}),  # these three: the generic (or KF) batched predict
           ("gc-svsf", {"covariance": "joseph"}), ("gc-svsf", {"ey_memory": "a_posteriori", "psi_y": 0.8}),
           ("gc-svsf", {"memory_after_miss": "reset", "psi_z": 0.2}),  # its batched update (issue 19)
           ("ekf", {"motion": "ct"}), ("gvbl-svsf", {"motion": "ct"}),  # CT: per-track Jacobians (f_many, ...)
           ("gvbl-svsf", {"motion": "ct", "psi_max": 0.5}),
           ("gvbl-svsf", {"motion": "ct", "memory_after_miss": "reset"})]


def _fields(s) -> dict:
    out = {k: v for k, v in vars(s).items() if k not in ("info", "F")}
    out.update({f"info.{k}": v for k, v in s.info.items()})
    return out


@pytest.mark.parametrize("kind, params", BATCHED, ids=[f"{k}-{'-'.join(map(str, p.values())) or 'default'}"
                                                        for k, p in BATCHED])
def test_the_batched_predict_and_update_equal_the_per_track_ones_to_1e_12(kind, params):
    """predict_many / predicted_measurements / update_many over 40 tracks and 10 scans (random gates, weights,
    misses, first updates without z_prev; CT models turning and straight) against the per-track predict /
    predicted_measurement / update (ModelFilter.update_many's loop): every field, the layers and diagnostics
    included, equal to 1e-12 (relative, or absolute near 0)."""
    from roadtrack.trackers.filters.base import ModelFilter

    flt = make_filter(kind, sigma_v=2.0, sigma_w=0.5, **params)
    rng = np.random.default_rng(3)
    states = [flt.initial_state(rng.normal(size=4) * [50, 5, 10, 2], np.diag([0.5, 0.5, 25.0, 25.0]))
              for _ in range(40)]
    if flt.motion.ndim == 5:  # turn rates 0, below the small-omega switch (1e-6 rad/s) and turning
        states = [replace(s, x=np.append(s.x[:4], rng.choice([0.0, 5e-7, 0.3]) * rng.normal())) for s in states]
    robust = 0
    for _ in range(10):
        batch, single = flt.predict_many(states, 0.1), [flt.predict(s, 0.1) for s in states]
        for u, v in zip(batch, single):
            for k in ("x", "P", "F"):
                np.testing.assert_allclose(getattr(u, k), getattr(v, k), rtol=1e-12, atol=1e-12, err_msg=k)
        z_hat, S = flt.predicted_measurements(batch)
        for t, s in enumerate(batch):
            z1, S1 = flt.predicted_measurement(s)
            np.testing.assert_allclose(z_hat[t], z1, rtol=1e-12, atol=1e-12)
            np.testing.assert_allclose(S[t], S1, rtol=1e-12, atol=1e-12)
        T, M = len(batch), 6
        nu = rng.normal(size=(T, M, 2)) * rng.choice([0.3, 3.0], size=(T, 1, 1))
        W = rng.random((T, M)) * (rng.random((T, M)) < 0.4)
        w0 = rng.random(T) * 0.6
        total = W.sum(axis=1, keepdims=True)
        W = np.where(total > 0, W / np.where(total > 0, total, 1.0) * (1.0 - w0)[:, None], 0.0)
        w0 = np.where(W.sum(axis=1) > 0, w0, 1.0)
        a, b = flt.update_many(batch, nu, W, w0), ModelFilter.update_many(flt, single, nu, W, w0)
        for u, v in zip(a, b):
            fu, fv = _fields(u), _fields(v)
            assert set(fu) == set(fv)
            for k in fu:
                if fu[k] is None or fv[k] is None:
                    assert fu[k] is None and fv[k] is None, k
                    continue
                np.testing.assert_allclose(fu[k], fv[k], rtol=1e-12, atol=1e-12, err_msg=k)
            robust += int(u.info.get("regime", 0.0) == 1.0)
        states = a
    if kind == "gvbl-svsf" and params.get("psi_max") == 0.5:
        assert robust > 0  # the robust (SVSF) gain was exercised, not only the KF one


# ---------------------------------------------------------------- the open choices of issue 21 (thesis silent)
def _svsf_prior(flt, x=(0.0, 0.0, 0.0, 0.0), z_prev=(-1.0, 0.0), tau=1.0, e_post=(0.0, 0.0)):
    """A predicted SVSFState by hand: x, P = I, projected measurement z_prev of the last update tau seconds ago."""
    from roadtrack.trackers.filters.svsf import SVSFState

    return SVSFState(x=np.array(x), P=np.eye(4), e_post=np.array(e_post), F=ConstantVelocity(1.0).transition(tau),
                     z_prev=np.array(z_prev), tau=tau, e_vel=np.zeros(2))


@pytest.mark.parametrize("psi, x_per_measurement, x_combined", [
    (1e-3, [1.0, 0.0, 1.75, 0.0], [1.0, 0.0, 2.0, 0.0]),  # saturated, gamma = 0: K e = e
    (10.0, [0.1, 0.0, 0.30625, 0.0], [0.1, 0.0, 0.4, 0.0]),  # inside the layer: K_jj = |e_j| / 10
])
def test_artificial_pda_per_measurement_or_combined_by_hand(psi, x_per_measurement, x_combined):
    """x_pred = 0, z_prev = (-1, 0), tau = 1 s; nu = [(2, 0), (0, 0)] with beta = (0.5, 0.25), beta0 = 0.25;
    gamma = 0, psi = psi_v. Position part e = nu_c = (1, 0) in both. Velocity part:
    per_measurement: sum_i beta_i ((z_hat + nu_i - z_prev) / tau - v) = 0.5 (3, 0) + 0.25 (1, 0) = (1.75, 0);
    combined: z^a = z_hat + nu_c = (1, 0), (z^a - z_prev) / tau - v = (2, 0).
    Gain (2.30) K_jj = |e_j| / max(|e_j|, psi): x = K e; e_post = e - K e."""
    nu, beta, beta0 = np.array([[2.0, 0.0], [0.0, 0.0]]), np.array([0.5, 0.25]), 0.25
    for mode, x_hand in (("per_measurement", x_per_measurement), ("combined", x_combined)):
        flt = make_filter("svsf", sigma_w=1.0, gamma=0.0, psi=psi, psi_v=psi, artificial_pda=mode)
        u = flt.update(_svsf_prior(flt), nu, beta, beta0)
        np.testing.assert_allclose(u.x, x_hand, rtol=1e-15, atol=1e-15, err_msg=mode)
        e_v = x_hand[2] if psi < 1 else (1.75 if mode == "per_measurement" else 2.0)
        np.testing.assert_allclose(np.r_[u.e_post, u.e_vel], [1.0 - x_hand[0], 0.0, e_v - x_hand[2], 0.0],
                                   rtol=0, atol=1e-15, err_msg=mode)  # (2.34) e - K e
        np.testing.assert_allclose(u.z_prev, [1.0, 0.0], rtol=0, atol=0)  # (2.32) z^a in both


@pytest.mark.parametrize("covariance", ["mse", "joseph", "short"])
def test_artificial_pda_forms_agree_when_beta0_is_zero(covariance):
    """With beta0 = 0 the combined artificial measurement is the weighted sum of the per-measurement ones: every
    field of the update equal to 1e-12; with beta0 = 0.3 the velocity estimates differ."""
    rng = np.random.default_rng(21)
    a, b = (make_filter("svsf", sigma_v=SV, sigma_w=SW, covariance=covariance, artificial_pda=m)
            for m in ("per_measurement", "combined"))
    sp = a.predict(a.predict(a.update(a.predict(a.initial_state(np.array([0.0, 0.0, 10.0, 2.0]),
                                                                np.diag([9.0, 9.0, 4.0, 4.0])), DT),
                                      np.array([[1.0, -2.0]]), np.ones(1), 0.0), DT), DT)
    nu = rng.normal(size=(3, 2)) * SW
    beta = rng.dirichlet(np.ones(3))
    ua, ub = a.update(sp, nu, beta, 0.0), b.update(sp, nu, beta, 0.0)
    for k in ("x", "P", "e_post", "e_vel", "z_prev"):
        np.testing.assert_allclose(getattr(ua, k), getattr(ub, k), rtol=1e-12, atol=1e-12, err_msg=k)
    va, vb = a.update(sp, nu, 0.7 * beta, 0.3).x[2:], b.update(sp, nu, 0.7 * beta, 0.3).x[2:]
    assert np.abs(va - vb).max() > 1e-3


@pytest.mark.parametrize("covariance", ["joseph", "short"])
@pytest.mark.parametrize("psi", [4.0, 1e-3])
def test_artificial_pda_spread_term_of_each_form_by_hand(covariance, psi):
    """The PDA covariance (4.16)-(4.17) of both artificial_pda forms, by hand. Prior as in the test above: x = 0,
    P = I, z_prev = (-1, 0), tau = 1 s, sigma_w = 1, gamma = 0, psi = psi_v; nu = [(2, 0), (0, 0)], beta = (0.5, 0.25),
    beta0 = 0.25. The hypotheses i = 0 (miss), 1, 2 have augmented innovations nu_bar_i (state order px, py, vx, vy):
    measurements nu_bar_i = [nu_i; (z_hat + nu_i - z_prev) / tau - v] = (2, 0, 3, 0), (0, 0, 1, 0); the miss has no
    measurement (nu_bar_0 = 0) in the per-measurement form and the artificial velocity of its projected measurement
    z_hat in the combined one (nu_bar_0 = (0, 0, 1, 0)), so that in both e = sum_i beta_i nu_bar_i (i = 0..2) is the
    innovation the gain acts on: (1, 0, 1.75, 0) per measurement, (1, 0, 2, 0) combined (= [nu_c; (z^a - z_prev) /
    tau - v], z^a = (1, 0)). H_bar = I, so K = diag(|e| / max(|e|, psi)); R_bar = [[R, R / tau], [R / tau,
    2 R / tau^2]].
    P = beta0 P + (1 - beta0) P* + K [sum_i beta_i (nu_bar_i - e)(nu_bar_i - e)^T] K^T, P* = (I - K) P (I - K)^T +
    K R_bar K^T (joseph) or (I - K) P (short). Combined, psi = 4, joseph: K = diag(0.25, 0, 0.5, 0), the spread's x
    block is [[1, 1], [1, 1]] and P_xx = 0.78125, P_x,vx = 0.21875, P_vx,vx = 1.0625, P_yy = P_vy,vy = 1."""
    nu, beta, beta0 = np.array([[2.0, 0.0], [0.0, 0.0]]), np.array([0.5, 0.25]), 0.25
    R_bar = np.kron([[1.0, 1.0], [1.0, 2.0]], np.eye(2))  # [17] with R = I, tau = 1, in the order px, py, vx, vy
    for form, miss in (("per_measurement", [0.0, 0.0, 0.0, 0.0]), ("combined", [0.0, 0.0, 1.0, 0.0])):
        bars = np.array([miss, [2.0, 0.0, 3.0, 0.0], [0.0, 0.0, 1.0, 0.0]])  # nu_bar_0, nu_bar_1, nu_bar_2
        w = np.array([beta0, *beta])
        e = w @ bars
        np.testing.assert_array_equal(e, [1.0, 0.0, 1.75 if form == "per_measurement" else 2.0, 0.0])
        K = np.diag(np.abs(e) / np.maximum(np.abs(e), psi))  # (2.30) with H_bar = I, gamma = 0
        I_K = np.eye(4) - K
        P_star = I_K @ I_K.T + K @ R_bar @ K.T if covariance == "joseph" else I_K
        spread = sum(wi * np.outer(b - e, b - e) for wi, b in zip(w, bars))
        P_hand = beta0 * np.eye(4) + (1.0 - beta0) * P_star + K @ spread @ K.T
        flt = make_filter("svsf", sigma_w=1.0, gamma=0.0, psi=psi, psi_v=psi, artificial_pda=form,
                          covariance=covariance)
        u = flt.update(_svsf_prior(flt), nu, beta, beta0)
        np.testing.assert_allclose(u.x, K @ e, rtol=0, atol=1e-15, err_msg=form)
        np.testing.assert_allclose(u.P, P_hand, rtol=0, atol=1e-14, err_msg=f"{form} {covariance}")
        if form == "combined" and covariance == "joseph" and psi == 4.0:
            np.testing.assert_allclose(u.P[np.ix_([0, 2], [0, 2])], [[0.78125, 0.21875], [0.21875, 1.0625]],
                                       rtol=0, atol=1e-15)
            np.testing.assert_allclose(u.P[[1, 3], [1, 3]], [1.0, 1.0], rtol=0, atol=1e-15)


@pytest.mark.parametrize("kind", ["svsf", "gc-svsf", "gvbl-svsf"])
def test_memory_after_a_miss_is_kept_or_reset(kind):
    """After a scan without update, "keep" returns the prediction itself and "reset" the prediction with
    e_{z,k-1|k-1} (and the svsf's e_vel) = 0, x and P unchanged; the next gain then has no gamma term.
    gc-svsf by hand: x_pred = 0, P = I, e_post = (0.4, 0.6), gamma = 0.5, psi_z = 10, nu = (2, -1):
    K_u = diag(E_z / 10) with E_z = |e| + 0.5 |e_post| = (2.2, 1.3) kept, (2, 1) reset, so
    x_u = K_u e = (0.44, -0.13) kept, (0.4, -0.1) reset."""
    from roadtrack.trackers.state import FilterState

    keep, reset = (make_filter(kind, sigma_v=SV, sigma_w=SW, memory_after_miss=m) for m in ("keep", "reset"))
    sp = predicted(keep, np.random.default_rng(22))
    assert np.abs(sp.e_post).max() > 0
    assert keep.update(sp, np.zeros((0, 2)), np.zeros(0), 1.0) is sp
    for nu, beta in ((np.zeros((0, 2)), np.zeros(0)), (np.ones((1, 2)), np.zeros(1))):
        r = reset.update(sp, nu, beta, 1.0)
        np.testing.assert_array_equal(r.e_post, [0.0, 0.0])
        if kind == "svsf":
            np.testing.assert_array_equal(r.e_vel, [0.0, 0.0])
        np.testing.assert_array_equal(r.x, sp.x)
        np.testing.assert_array_equal(r.P, sp.P)
    if kind != "gc-svsf":
        return
    s0 = FilterState(x=np.zeros(4), P=np.eye(4), e_post=np.array([0.4, 0.6]), F=ConstantVelocity(SV).transition(DT))
    for m, x_u in (("keep", [0.44, -0.13]), ("reset", [0.4, -0.1])):
        flt = make_filter("gc-svsf", sigma_v=SV, sigma_w=SW, gamma=0.5, psi_z=10.0, memory_after_miss=m)
        missed = flt.update(s0, np.zeros((0, 2)), np.zeros(0), 1.0)
        u = flt.update(missed, np.array([[2.0, -1.0]]), np.ones(1), 0.0)
        np.testing.assert_allclose(u.x[:2], x_u, rtol=0, atol=1e-15, err_msg=m)


def test_memory_reset_reaches_the_trackers_batched_update_on_an_empty_scan():
    """pda-gvbl-svsf, pda-svsf and imm-pda-svsf (both modes) with memory_after_miss = "reset": after an empty scan
    every track's memory (the IMM's mu-weighted one and each mode's) is 0; with "keep" it is the memory of the last
    update (non-zero; the IMM's after its mixing, issue 33)."""
    Z = [np.array([[0.0, 0.0], [30.0, 5.0]]), np.array([[2.1, 0.1], [32.0, 5.2]]), np.array([[4.3, 0.1], [34.2, 5.1]])]
    for name in ("pda-gvbl-svsf", "pda-svsf", "imm-pda-svsf"):
        for mode in ("keep", "reset"):
            if name.startswith("imm"):
                table = {"memory_after_miss": mode}
                trk = make_tracker(name, sigma_v=4.0, sigma_w=0.5, filter={"svsf": table, "gvbl-svsf": table})
            else:
                trk = make_tracker(name, sigma_v=4.0, sigma_w=0.5, memory_after_miss=mode)
            tracks, nid = (), 1
            for z in Z + [np.zeros((0, 2))]:
                res = trk.step(tracks, z, 0.1, nid)
                before, tracks, nid = tracks, res.tracks, res.next_id
            live = [t for t in tracks if not t.candidate]
            assert len(live) == 2
            memory = np.array([t.state.e_post for t in live] + [m.e_post for t in live
                                                                for m in getattr(t.state, "modes", ())])
            if mode == "reset":
                np.testing.assert_array_equal(memory, 0.0)
            else:
                assert np.abs(memory).max() > 1e-3, name
                if not name.startswith("imm"):
                    np.testing.assert_array_equal(memory, [t.state.e_post for t in before if not t.candidate])


def test_apda_layer_previous_capped_or_psi_max_by_hand():
    """GVBL, P = I, sigma_w = 1 (S = 2 I), e_post = 0, one measurement nu = (0.5, -0.25): E_z = |e| and
    Psi_z = S P11^-1 diag(E_z) = (1.0, 0.5) (4.61), below psi_max = 5 (optimal regime). The next scan's layer is
    (1.0, 0.5) with "previous_capped" and (5, 5) with "psi_max"; before any update both report psi_max.
    Through apda-gvbl-svsf on a scan with one measurement at nu = (2, 0): chattering C = max(0, |nu| - layer)
    (5.37) = (1, 0), norm 1, and APDA active; with "psi_max" C = 0 and the weights are the PDA's."""
    from roadtrack.trackers.filters.gvbl import GVBLState
    from roadtrack.trackers.tracker import Track

    for mode, lay in (("previous_capped", [1.0, 0.5]), ("psi_max", [5.0, 5.0])):
        flt = make_filter("gvbl-svsf", sigma_v=1.0, sigma_w=1.0, psi_max=5.0, apda_layer=mode)
        s0 = flt.initial_state(np.zeros(4), np.eye(4))
        sp = flt.predict(s0, 0.0)  # dt = 0: P stays I, Q = 0
        np.testing.assert_array_equal(flt.layer(sp), [5.0, 5.0])
        u = flt.update(sp, np.array([[0.5, -0.25]]), np.ones(1), 0.0)
        assert u.info["regime"] == 0.0
        np.testing.assert_allclose(u.info["psi_z"], [1.0, 0.5], rtol=1e-15, atol=0)
        np.testing.assert_allclose(flt.layer(flt.predict(u, 0.1)), lay, rtol=1e-15, atol=0, err_msg=mode)
        trk = make_tracker("apda-gvbl-svsf", sigma_v=1.0, sigma_w=1.0, psi_max=5.0, apda_layer=mode)
        state = GVBLState(x=np.zeros(4), P=np.eye(4), e_post=np.zeros(2), psi_layer=np.array([1.0, 0.5]))
        track = Track(id=1, state=state, score=10.0, max_score=10.0, confirmed=True, age=5, hits=5, misses_in_a_row=0)
        res = trk.step((track,), np.array([[2.0, 0.0]]), 0.0, 2)
        np.testing.assert_allclose(res.info.layers[0], lay, rtol=1e-15, atol=0, err_msg=mode)
        d = res.info.diagnostics
        chatter = 1.0 if mode == "previous_capped" else 0.0
        assert d["chattering"][0] == pytest.approx(chatter, abs=1e-15) and d["apda_active"][0] == chatter, mode


@pytest.mark.parametrize("kind, key, allowed", [("svsf", "artificial_pda", "per_measurement, combined"),
                                                ("svsf", "memory_after_miss", "keep, reset"),
                                                ("gc-svsf", "memory_after_miss", "keep, reset"),
                                                ("gvbl-svsf", "memory_after_miss", "keep, reset"),
                                                ("gvbl-svsf", "apda_layer", "previous_capped, psi_max")])
def test_a_bad_switch_value_is_a_one_line_error(kind, key, allowed):
    with pytest.raises(ParamError) as info:
        make_filter(kind, **{key: "sometimes"})
    assert str(info.value) == f"filter.{key}: 'sometimes' is not allowed; allowed: {allowed}"
    built = make_filter(kind)
    with pytest.raises(ValueError, match=f"{key} must be one of"):
        type(built)(built.motion, built.measurement, **{key: "sometimes"})  # the filter checks its own fields too
