"""Paper 000's pieces: the mixed-measurement sensor (sensors/mixed.py), the windowed KS integral test
(trackers/trackloss/ks_integral.py) and the convoy-of-point-targets scenario with its EKF/PDAF loop
(testbed/reproduce/seed000/convoy_points.py). The paper's claims are in tests/test_reproduce_seed000.py."""

from __future__ import annotations

import ast
import math
from pathlib import Path

import numpy as np
import pytest
from scipy.stats import ks_2samp

from roadtrack.sensors.mixed import mixed_measurements, wrong_steps
from roadtrack.testbed.reproduce.seed000 import convoy_points as cp
from roadtrack.trackers.association.params import AssociationParams
from roadtrack.trackers.association.pda import pda
from roadtrack.trackers.gating import log_gaussian
from roadtrack.trackers.tracker import gate_volume
from roadtrack.trackers.trackloss import ks_integral as ksi

ROOT = Path(__file__).resolve().parent.parent


# ------------------------------------------------------------------------------------------ sensor
@pytest.mark.parametrize("fraction,count", [(0.1, 100), (0.0, 0), (1.0, 1000), (0.0125, 12)])
def test_fraction_mode_gives_an_exact_count_of_distinct_steps(fraction, count):
    mask = wrong_steps(1000, fraction, np.random.default_rng(1))
    assert mask.dtype == np.bool_ and mask.shape == (1000,) and int(mask.sum()) == count


def test_probability_mode_share_within_binomial_bounds():
    K, p = 100_000, 0.1
    share = wrong_steps(K, p, np.random.default_rng(2), mode="probability").mean()
    assert abs(share - p) < 4.0 * math.sqrt(p * (1 - p) / K)  # 4 sigma: 0.0038


def test_measurements_come_from_the_stated_car_with_the_stated_noise():
    rng = np.random.default_rng(3)
    K, sigma = 20_000, 0.5
    pos = rng.uniform(-50, 50, size=(K, 2, 2))
    mask = wrong_steps(K, 0.1, np.random.default_rng(4))
    m = mixed_measurements(pos, 0, sigma, mask, np.random.default_rng(5))
    np.testing.assert_array_equal(m.origin, np.where(mask, 1, 0))
    np.testing.assert_array_equal(m.wrong(0), mask)
    chi2 = np.sum((m.z - pos[np.arange(K), m.origin]) ** 2) / sigma ** 2  # chi-square with 2K dof
    assert abs(chi2 - 2 * K) < 5.0 * math.sqrt(4 * K)


def test_noise_does_not_depend_on_the_mixing():
    pos = np.zeros((500, 2, 2))
    a = mixed_measurements(pos, 0, 0.5, wrong_steps(500, 0.1, np.random.default_rng(1)), np.random.default_rng(9))
    b = mixed_measurements(pos, 0, 0.5, wrong_steps(500, 0.3, np.random.default_rng(1)), np.random.default_rng(9))
    np.testing.assert_array_equal(a.per_car, b.per_car)
    np.testing.assert_array_equal(a.z[~(a.wrong(0) | b.wrong(0))], b.z[~(a.wrong(0) | b.wrong(0))])


def test_wrong_measurements_come_from_adjacent_cars_only_and_evenly():
    K = 10_000
    mask = np.ones(K, dtype=bool)
    m = mixed_measurements(np.zeros((K, 4, 2)), 1, 0.5, mask, np.random.default_rng(6))
    assert set(np.unique(m.origin)) == {0, 2}
    assert abs(np.mean(m.origin == 0) - 0.5) < 4.0 * math.sqrt(0.25 / K)


@pytest.mark.parametrize("call", [
    lambda: wrong_steps(10, 1.5, np.random.default_rng()),
    lambda: wrong_steps(10, 0.1, np.random.default_rng(), mode="sometimes"),
    lambda: mixed_measurements(np.zeros((5, 2, 2)), 2, 0.5, np.zeros(5, bool), np.random.default_rng()),
    lambda: mixed_measurements(np.zeros((5, 2, 2)), 0, 0.5, np.zeros(4, bool), np.random.default_rng()),
    lambda: mixed_measurements(np.zeros((5, 1, 2)), 0, 0.5, np.ones(5, bool), np.random.default_rng()),
    lambda: mixed_measurements(np.zeros((5, 2, 2)), 0, 0.0, np.zeros(5, bool), np.random.default_rng()),
])
def test_sensor_rejects_bad_input_with_one_line(call):
    with pytest.raises(ValueError) as err:
        call()
    assert "\n" not in str(err.value)


def test_sensor_module_does_not_import_trackers():
    tree = ast.parse((ROOT / "sensors" / "mixed.py").read_text())
    names = [a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names]
    names += [n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)]
    assert not [n for n in names if n and n.removeprefix("roadtrack.").split(".")[0] in ("trackers", "testbed")], names


# ------------------------------------------------------------------------------------------ KS integral
def test_ks_integral_and_sup_on_a_hand_computed_case():
    """ref {1, 2, 3}, window {0.5, 4}: int (F0 - Sn) = -0.25 (on [.5, 1)) - 1/6 + 1/6 + 0.5 (on [3, 4)) = 0.25;
    sup |Sn - F0| = 0.5 (at 0.5 and on [3, 4))."""
    ref, w = np.array([1.0, 2.0, 3.0]), np.array([0.5, 4.0])
    assert ksi.ks_integral(w, ref) == pytest.approx(0.25, abs=1e-15)
    assert ksi.ks_sup(w, ref) == pytest.approx(0.5, abs=1e-15)
    np.testing.assert_array_equal(ksi.empirical_cdf(ref, [0.0, 1.0, 2.5, 3.0, 9.0]), [0, 1 / 3, 2 / 3, 1, 1])


def test_ks_integral_equals_window_mean_minus_reference_mean():
    rng = np.random.default_rng(7)
    ref = rng.rayleigh(0.5, 2000)
    for _ in range(50):
        w = rng.rayleigh(0.5, 10) + rng.uniform(0, 3) * (rng.random(10) < 0.1)
        assert ksi.ks_integral(w, ref) == pytest.approx(w.mean() - ref.mean(), abs=1e-12)


def test_ks_sup_is_the_two_sample_ks_statistic():
    rng = np.random.default_rng(8)
    ref = rng.rayleigh(0.5, 3000)
    for _ in range(20):
        w = rng.rayleigh(0.6, 10)
        assert ksi.ks_sup(w, ref) == pytest.approx(ks_2samp(w, ref).statistic, abs=1e-12)
    ties_ref = rng.integers(0, 5, 300).astype(float)  # ties inside and across the samples
    for _ in range(20):
        w = rng.integers(0, 6, 10).astype(float)
        assert ksi.ks_sup(w, ties_ref) == pytest.approx(ks_2samp(w, ties_ref).statistic, abs=1e-12)


def test_windowed_metrics_match_the_per_window_functions():
    rng = np.random.default_rng(9)
    x, ref = rng.rayleigh(0.5, 40), rng.rayleigh(0.5, 500)
    D, Dsup = ksi.windowed(x, ref, 10), ksi.windowed(x, ref, 10, "sup")
    assert D.shape == Dsup.shape == (31,)
    for w in (0, 17, 30):
        assert D[w] == pytest.approx(ksi.ks_integral(x[w: w + 10], ref), abs=1e-12)
        assert Dsup[w] == ksi.ks_sup(x[w: w + 10], ref)


def test_one_outlier_makes_a_hump_exactly_n_windows_wide():
    x = np.ones(100)
    x[40] = 11.0
    D = ksi.windowed(x, np.ones(50), 10)
    expected = np.zeros(91)
    expected[31:41] = 1.0  # windows 31..40 (0-based) hold sample 40; each rises by (11 - 1) / 10
    np.testing.assert_allclose(D, expected, atol=1e-14)
    flagged = ksi.flag_samples(D > 0.5, 10)
    np.testing.assert_array_equal(np.flatnonzero(flagged), [40])


def test_flag_samples_flags_the_clean_samples_between_two_close_wrong_ones():
    x = np.ones(60)
    x[[20, 24]] = 11.0
    flagged = ksi.flag_samples(ksi.windowed(x, np.ones(50), 10) > 0.5, 10)
    np.testing.assert_array_equal(np.flatnonzero(flagged), np.arange(20, 25))


def test_clean_threshold_false_alarm_rate_on_a_fresh_clean_stream():
    """k_sigma = 3 on Rayleigh innovation norms: about 0.3 % of clean windows above (normal: 0.13 %; the window
    mean of 10 Rayleigh values is slightly right-skewed). Asserted: below 1 %."""
    rng = np.random.default_rng(10)
    thr = ksi.clean_threshold(rng.rayleigh(0.5, 20_000), 10, 3.0)
    ref = rng.rayleigh(0.5, 20_000)
    above = np.mean(ksi.windowed(rng.rayleigh(0.5, 20_000), ref, 10) > thr)
    assert 0.0 < above < 0.01


@pytest.mark.parametrize("bad", [np.array([0.1, -0.2]), np.array([np.nan, 1.0]), np.zeros((2, 2))])
def test_ks_integral_rejects_negative_or_bad_samples(bad):
    with pytest.raises(ValueError):
        ksi.ks_integral(bad, np.ones(3))


# ------------------------------------------------------------------------------------------ convoy scenario
def test_road_ode_is_the_papers_constrained_euler_lagrange_solution():
    """For g = sin x: xddot = sin(2x) xdot^2 / (3 + cos 2x) (paper 000, the lambda of eq. (37)), and the
    acceleration is normal to the road (constraint forces do no work)."""
    road = cp.SineRoad(1.0, 1.0)
    x, xd = np.linspace(-3, 3, 13), np.linspace(0.5, 2.0, 13)
    q = np.stack([x, np.sin(x), xd, np.cos(x) * xd], axis=-1)
    dq = cp.road_ode(q, road)
    np.testing.assert_allclose(dq[:, 2], np.sin(2 * x) * xd ** 2 / (3 + np.cos(2 * x)), rtol=1e-13, atol=1e-15)
    tangent = np.stack([np.ones_like(x), np.cos(x)], axis=-1)
    assert np.abs(np.einsum("ij,ij->i", dq[:, 2:], tangent)).max() < 1e-13  # M qddot = lambda omega^T


def test_rk4_truth_conserves_speed_and_stays_on_the_road_without_projection():
    """Claim C000-7: xdot^2 (1 + g'^2) = v^2 and y = g(x) along 3 km of the paper's road (half a period)."""
    road = cp.SineRoad()
    q = cp.on_road(np.array([0.0]), 30.0, road)[0]
    speeds, off_road = [], []
    for _ in range(10_000):
        q = cp.rk4_step(q, 0.01, road)
        speeds.append(q[2] ** 2 * (1 + road.dg(q[0]) ** 2))
        off_road.append(abs(q[1] - road.g(q[0])))
    assert q[0] > 2500.0
    assert np.max(np.abs(np.array(speeds) / 900.0 - 1.0)) < 1e-9 and max(off_road) < 1e-6


def test_filter_step_equals_the_truth_integrator_step():
    mot = cp.RoadMotion(cp.SineRoad(), 0.1)
    q = cp.on_road(np.array([-300.0, 800.0, 2400.0]), 30.0, mot.road)
    for dt in (1e-4, 0.1):
        np.testing.assert_allclose(np.array([mot.f(x, dt) for x in q]), cp.rk4_step(q, dt, mot.road), rtol=1e-14,
                                   atol=1e-12)


def test_convoy_cars_start_at_the_requested_euclidean_separation_on_the_road():
    scn = cp.ConvoyScenario(cars=3, separation_m=2.0, x0_m=700.0)
    q = scn.initial_states()
    np.testing.assert_allclose(np.hypot(*np.diff(q[:, :2], axis=0).T), [2.0, 2.0], atol=1e-9)
    np.testing.assert_allclose(q[:, 1], scn.road.g(q[:, 0]), atol=1e-9)
    np.testing.assert_allclose(np.hypot(q[:, 2], q[:, 3]), 30.0, rtol=1e-12)


def test_motion_jacobian_matches_central_differences():
    mot = cp.RoadMotion(cp.SineRoad(), 0.1)
    x = cp.on_road(np.array([800.0]), 30.0, mot.road)[0]
    for dt in (1e-4, 0.5):
        F, num = mot.jacobian(x, dt), np.zeros((4, 4))
        for j in range(4):
            h = 1e-4 * max(1.0, abs(x[j]))
            e = np.zeros(4)
            e[j] = h
            num[:, j] = (mot.f(x + e, dt) - mot.f(x - e, dt)) / (2 * h)
        np.testing.assert_allclose(F, num, rtol=1e-6, atol=1e-8)


def test_simulation_is_seeded_and_mixes_the_stated_share():
    scn = cp.ConvoyScenario(separation_m=2.0, steps=500)
    a, b = cp.simulate(scn, 11), cp.simulate(scn, 11)
    np.testing.assert_array_equal(a.z, b.z)
    assert int(a.wrong.sum()) == 50 and np.all(a.origin[a.wrong] == 1)
    fixed = cp.simulate(cp.ConvoyScenario(steps=210, wrong_at=(27, 58)), 11)
    np.testing.assert_array_equal(np.flatnonzero(fixed.wrong), [27, 58])


@pytest.mark.parametrize("pd,pg,nu", [(1.0, 0.971, [0.3, -0.2]), (0.98, 0.971, [1.0, 0.7]), (0.9, 1.0, [2.0, 2.0])])
def test_pdaf_weights_are_trackers_pda_with_the_sample_density(pd, pg, nu):
    """paper 000 eqs. (25)-(29) in b form equal trackers' PDA with lambda = m_k / V_k (eq. (27))."""
    S = np.array([[0.26, 0.01], [0.01, 0.25]])
    nu = np.array(nu)
    d2, ok, beta1, beta0 = cp.pda_weights(cp.Association(gate=pg < 1.0, gamma=9.0, pd=pd, pg=pg), nu, S)
    lam = 1.0 / gate_volume(S[None], 9.0)[0]
    W, w0 = pda(log_gaussian(nu[None, None], S[None]), np.ones((1, 1), bool), AssociationParams(pd, pg, lam))
    assert ok and beta1 == pytest.approx(W[0, 0], rel=1e-12) and beta0 == pytest.approx(w0[0], rel=1e-12)


def test_b_values_of_the_paper_settings():
    """b of eq. (29), c_nz as a divisor [R]: 0.00644 (gated far), 0.01098 (gated close), 0.0247 (gamma_ref 9)."""
    assert cp.Association(pd=1.0, pg=0.971).b() == pytest.approx(0.006444, abs=5e-6)
    assert cp.Association(pd=0.98, pg=0.971).b() == pytest.approx(0.010980, abs=5e-6)
    assert cp.Association(gate=False, gamma=9.0, pd=0.9, pg=1.0).b() == pytest.approx(0.024691, abs=5e-6)
    assert cp.Association(gate=False, gamma=None).b() == 0.0


def test_gated_loop_drops_outside_the_gate_and_ungated_loop_takes_everything():
    scn = cp.ConvoyScenario(separation_m=5.0, steps=300)
    run = cp.simulate(scn, 12)
    gated = cp.track(run, scn, cp.Association())
    assert np.all(gated.validated == (gated.d2 <= 9.0)) and not gated.validated[run.wrong].any()
    flt = scn.filter()
    for k in np.flatnonzero(~gated.validated)[:5]:
        s = flt.initial_state(gated.x[k], gated.P[k])
        np.testing.assert_allclose(gated.x[k + 1], flt.predict(s, scn.dt).x, rtol=0, atol=1e-12)
    ungated = cp.track(run, scn, cp.Association(gate=False, gamma=None))
    assert ungated.validated.all() and np.all(ungated.beta0 == 0.0)
    P = gated.P[-1]
    assert np.abs(P - P.T).max() == 0.0 and np.linalg.eigvalsh(P)[0] > 0.0
