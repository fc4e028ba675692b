"""Paper 003, symmetric measurement equations: the sensors' noise moments (sensors.symmetric), the joint EKF and
its labelling (trackers.sme), the crossing-targets scenario (testbed.reproduce.seed003.sme_targets), and the paper's claims on a
reduced seeded Monte Carlo.

ROADTRACK_FULL=1 runs the paper's 100-run Monte Carlo (marked slow; about 10 s of one core), which adds the
sum-of-products-below-sum-of-powers claim: at 20 runs that ordering is not robust (seeds 0-5: the two means of
target 1 are 0.40-0.47 m and differ by 0.006-0.10 m, products lower every time but within the run-to-run spread).
"""

import itertools
import math
import os

import numpy as np
import pytest

from roadtrack.sensors.symmetric import SymmetricSensor, monte_carlo_moments
from roadtrack.testbed.reproduce.seed003 import sme_targets as st
from roadtrack.testbed.reproduce.seed003 import study as s3
from roadtrack.trackers.filters import ExtendedKalmanFilter
from roadtrack.trackers.sme import (SMEState, SMETracker, SymmetricMeasurement, label_permutation, permutations, relabel,
                          symmetric_g, symmetric_h, symmetric_jacobian, symmetric_noise_covariance,
                          symmetric_noise_mean)

FULL = bool(os.environ.get("ROADTRACK_FULL"))
FORMS = ("powers", "products")
# (N, positions [m], sigma [m]): far apart, the paper's truth, negative, near-coincident, small sigma
CASES = [(2, (3.0, 25.0), 5.0), (2, (-40.0, 10.0), 5.0), (2, (10.0, 10.1), 5.0), (3, (3.0, 25.0, 120.0), 5.0),
         (3, (50.0, 10.0, 120.0), 5.0), (3, (1.0, -2.0, 0.5), 2.0), (3, (10.0, 10.1, -3.0), 5.0)]


# ----------------------------------------------------------------------------------- noise moments
@pytest.mark.parametrize("form", FORMS)
@pytest.mark.parametrize("n,x,sigma", CASES)
def test_analytic_noise_moments_match_monte_carlo(form, n, x, sigma):
    """C003-1: the closed-form E[nu] and R(x) against 4e5 seeded samples: every entry within 5 standard errors
    of the Monte Carlo estimate (SE from the sample spread of nu_a nu_b) and within 2 % of sqrt(R_aa R_bb); the
    raw noise's sample variance within 5 SE of sigma^2."""
    sen = SymmetricSensor(form, n, sigma)
    mc = monte_carlo_moments(sen, np.array(x), 400_000, np.random.default_rng(31))
    R, mean = sen.noise_covariance(np.array(x)), sen.noise_mean(np.array(x))
    assert np.all(np.abs(mc.cov - R) <= 5 * mc.cov_se), ((mc.cov - R) / mc.cov_se)
    assert np.all(np.abs(mc.cov - R) <= 0.02 * np.sqrt(np.outer(np.diag(R), np.diag(R))))
    assert np.all(np.abs(mc.mean - mean) <= 5 * mc.mean_se), ((mc.mean - mean) / mc.mean_se)
    assert np.all(np.abs(mc.raw_var - 1.0) <= 5 * np.sqrt(2.0 / mc.n)), mc.raw_var


def test_noise_mean_of_the_sum_of_powers():
    """Paper 003 §II: E[nu] = [0, 2 sigma^2] for two targets; for three [0, 3 sigma^2, 3 sigma^2 S_1]
    (reconstructed); zero for the sum of products."""
    x3 = np.array([3.0, 25.0, 120.0])
    np.testing.assert_allclose(SymmetricSensor("powers", 2).noise_mean(x3[:2]), [0.0, 50.0], rtol=0, atol=1e-12)
    np.testing.assert_allclose(SymmetricSensor("powers", 3).noise_mean(x3), [0.0, 75.0, 75.0 * 148.0], rtol=1e-15)
    np.testing.assert_array_equal(SymmetricSensor("products", 3).noise_mean(x3), np.zeros(3))


@pytest.mark.parametrize("form", FORMS)
@pytest.mark.parametrize("n", (2, 3))
def test_sensor_and_filter_transformations_agree(form, n):
    """The sensor's closed forms (sensors/symmetric.py) and the filter's general-N formulas (trackers/sme.py) are
    independent derivations: transform = g, transform + E[nu] = h, and R agree to 1e-12 relative on 200 random
    position sets, including zeros, coincident and negative positions, in a batch."""
    rng = np.random.default_rng(7)
    x = rng.normal(0.0, 60.0, (200, n))
    x[0] = 0.0
    x[1, 1] = x[1, 0]
    sen = SymmetricSensor(form, n, 5.0)
    scale = np.abs(sen.noise_covariance(x)).max(axis=(-2, -1))[:, None, None]
    np.testing.assert_allclose(symmetric_g(x, form), sen.transform(x), rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(symmetric_h(x, form, 5.0), sen.transform(x) + sen.noise_mean(x), rtol=1e-12,
                               atol=1e-9)
    assert np.all(np.abs(symmetric_noise_covariance(x, form, 5.0) - sen.noise_covariance(x)) <= 1e-12 * scale)
    meas = SymmetricMeasurement(form, n, 5.0)
    state = np.concatenate([x, rng.normal(size=x.shape)], axis=1)
    np.testing.assert_array_equal(meas.h(state), symmetric_h(x, form, 5.0))
    np.testing.assert_array_equal(symmetric_noise_mean(x, form, 5.0), symmetric_h(x, form, 5.0) - symmetric_g(x, form))


@pytest.mark.parametrize("form", FORMS)
@pytest.mark.parametrize("n", (2, 3))
def test_noise_covariance_is_positive_definite_even_where_targets_meet(form, n):
    """R(x) is symmetric positive definite at random, coincident and all-zero positions (the sigma^4 terms keep it
    so where J is singular)."""
    rng = np.random.default_rng(8)
    x = rng.normal(0.0, 50.0, (100, n))
    x[:10, 1] = x[:10, 0]
    x[10] = 0.0
    R = symmetric_noise_covariance(x, form, 5.0)
    np.testing.assert_allclose(R, np.swapaxes(R, -1, -2), rtol=1e-15, atol=0)
    ev = np.linalg.eigvalsh(R / np.abs(R).max(axis=(-2, -1))[:, None, None])
    assert ev.min() > 1e-14, ev.min()


# ------------------------------------------------------------------------------------------ Jacobian
@pytest.mark.parametrize("form", FORMS)
@pytest.mark.parametrize("n", (2, 3))
def test_jacobian_matches_central_differences(form, n):
    """C003-2: dh/dx against central differences (step 1e-4 m), within 1e-6 of each row's largest entry."""
    rng = np.random.default_rng(9)
    for x in rng.normal(0.0, 60.0, (20, n)):
        J = symmetric_jacobian(x, form, 5.0)
        fd = np.empty_like(J)
        for i in range(n):
            e = np.zeros(n)
            e[i] = 1e-4
            fd[:, i] = (symmetric_h(x + e, form, 5.0) - symmetric_h(x - e, form, 5.0)) / 2e-4
        assert np.all(np.abs(J - fd) <= 1e-6 * np.abs(J).max(axis=1, keepdims=True)), (J, fd)


@pytest.mark.parametrize("form,const", [("powers", {2: 2.0, 3: 6.0}), ("products", {2: 1.0, 3: 1.0})])
@pytest.mark.parametrize("n", (2, 3))
def test_jacobian_determinant_is_the_vandermonde_product(form, const, n):
    """det J = c prod_{i<j} (x_i - x_j) up to sign (c = n! for powers, 1 for products): J is singular exactly
    where two targets meet (there individual positions are locally unobservable)."""
    rng = np.random.default_rng(10)
    x = rng.normal(0.0, 30.0, (50, n))
    vdm = np.prod([x[:, i] - x[:, j] for i, j in itertools.combinations(range(n), 2)], axis=0)
    det = np.linalg.det(symmetric_jacobian(x, form, 5.0))
    np.testing.assert_allclose(np.abs(det), const[n] * np.abs(vdm), rtol=1e-9)
    meet = x.copy()
    meet[:, 1] = meet[:, 0]
    assert np.all(np.abs(np.linalg.det(symmetric_jacobian(meet, form, 5.0))) <= 1e-9 * (1 + np.abs(x).max()) ** n)


# -------------------------------------------------------------------------------------------- filter
class _FrozenR:
    """The SME measurement with R frozen at one state, in the core's measurement-model interface."""

    linear = False

    def __init__(self, meas: SymmetricMeasurement, x_at: np.ndarray):
        self.meas, self.R, self.ndim = meas, meas.noise(x_at), meas.n_targets

    def h(self, x, motion):
        return self.meas.h(x)

    def jacobian(self, x, motion):
        return self.meas.jacobian(x)

    def residual(self, z, z_hat):
        return z - z_hat


@pytest.mark.parametrize("form", FORMS)
def test_update_equals_the_core_ekf_with_R_at_the_prediction(form):
    """One SME update equals trackers.filters.ExtendedKalmanFilter's update (beta = [1]) with R(x) frozen at the
    prediction: state and covariance to 1e-9 relative."""
    trk = SMETracker(SymmetricMeasurement(form, 3, 5.0))
    s = trk.predict(SMEState(x=np.array([2.0, 30.0, 110.0, 9.0, 6.0, 1.0]), P=np.diag([4.0, 9, 16, 1, 2, 3])), 0.01)
    y = symmetric_h(np.array([3.0, 25.0, 120.0]), form, 5.0) + np.array([1.0, -50.0, 3000.0])
    ours = trk.update(s, y)
    ekf = ExtendedKalmanFilter(trk.motion, _FrozenR(trk.measurement, s.x))
    core = ekf.update(ekf.initial_state(s.x, s.P), (y - trk.measurement.h(s.x))[None], np.ones(1), 0.0)
    np.testing.assert_allclose(ours.x, core.x, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(ours.P, core.P, rtol=1e-9, atol=1e-9 * np.abs(core.P).max())


@pytest.mark.parametrize("form", FORMS)
def test_batched_steps_equal_single_steps(form):
    """A batch of 4 runs stepped at once equals the 4 runs stepped one by one (1e-12 relative), and the
    covariance stays symmetric positive definite over 300 steps."""
    scn = st.paper_scenario(3, steps=300)
    runs = st.simulate(scn, 4, seed=5)
    batch = st.track_symmetric(scn, runs, form)
    trk = SMETracker(SymmetricMeasurement(form, 3, scn.sigma))
    x0, P0 = scn.initial_estimate
    y = runs.symmetric(form)
    for r in range(4):
        s = trk.initial_state(x0, P0)
        for k in range(scn.steps):
            s, est = trk.step(s, y[r, k], scn.dt)
        np.testing.assert_allclose(s.x, batch[r, -1], rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(est, np.stack([s.x[:3], s.x[3:]], axis=-1), rtol=0, atol=0)
        assert np.array_equal(s.P, s.P.T) and np.linalg.eigvalsh(s.P).min() > 0


@pytest.mark.parametrize("form", FORMS)
def test_update_is_permutation_equivariant(form):
    """C003-3: relabelling the prior's slots relabels the posterior (1e-9 relative): the EKF cannot tell the
    slots apart, so from x0 = 0 with equal P0 position entries its first update leaves every slot equal. The
    default P0 [D] has unequal entries and separates the slots at once (by more than 1 m; measured 6 m)."""
    trk = SMETracker(SymmetricMeasurement(form, 3, 5.0))
    rng = np.random.default_rng(11)
    x = rng.normal(50.0, 30.0, 6)
    A = rng.normal(size=(6, 6))
    P = A @ A.T + np.eye(6)
    y = symmetric_h(np.array([3.0, 25.0, 120.0]), form, 5.0)
    post = trk.update(SMEState(x, P), y)
    for p in permutations(3):
        idx = np.concatenate([p, p + 3])
        moved = trk.update(SMEState(x[idx], P[np.ix_(idx, idx)]), y)
        np.testing.assert_allclose(moved.x, post.x[idx], rtol=1e-9, atol=1e-9 * np.abs(post.x).max())
    sym = trk.update(trk.predict(SMEState(np.zeros(6), np.diag([100.0] * 3 + [25.0] * 3)), 0.01), y)
    assert np.ptp(sym.x[:3]) <= 1e-9 * np.abs(sym.x[:3]).max()
    x0, P0 = st.paper_scenario(3).initial_estimate
    first = trk.update(trk.predict(SMEState(x0, P0), 0.01), y)
    assert np.diff(np.sort(first.x[:3])).min() > 1.0, first.x[:3]


@pytest.mark.parametrize("form", FORMS)
def test_ekf_converges_on_a_seeded_run(form):
    """C003-4 (one run, seed 0, the paper's set-up): after 20 s the labelled estimate of every target is within
    1.5 m and 0.5 m/s of the truth (the associated KF's final position std is about 0.22 m)."""
    scn = st.paper_scenario(3)
    runs = st.simulate(scn, 1, seed=0)
    est, _ = st.labelled(st.track_symmetric(scn, runs, form), runs.truth)
    err = np.abs(est[0, -1] - runs.truth[-1])
    assert np.all(err[:3] < 1.5) and np.all(err[3:] < 0.5), err


# ------------------------------------------------------------------------------------------ labelling
def test_labelling_picks_the_permutation_of_minimum_squared_error():
    """Slots holding truth shuffled by every permutation (plus 0.1 noise) are put back; where two positions
    coincide the velocities decide; the chosen cost equals a brute-force minimum over all permutations."""
    rng = np.random.default_rng(12)
    truth = np.array([3.0, 25.0, 120.0, 10.0, 5.0, 0.0])
    for p in permutations(3):
        est = truth[np.concatenate([p, p + 3])] + rng.normal(0.0, 0.1, 6)
        perm = label_permutation(est, truth)
        np.testing.assert_allclose(relabel(est, perm), truth, atol=0.5)
    meet = np.array([47.0, 47.0, 120.0, 10.0, 5.0, 0.0])
    swapped = meet[[1, 0, 2, 4, 3, 5]]
    np.testing.assert_array_equal(label_permutation(swapped, meet), [1, 0, 2])
    ests, truths = rng.normal(0.0, 20.0, (200, 6)), rng.normal(0.0, 20.0, (200, 6))
    perm = label_permutation(ests, truths)
    cost = ((relabel(ests, perm) - truths) ** 2).sum(axis=-1)
    brute = np.min([((ests[:, np.concatenate([q, q + 3])] - truths) ** 2).sum(axis=-1) for q in permutations(3)],
                   axis=0)
    np.testing.assert_allclose(cost, brute, rtol=1e-12)


# ------------------------------------------------------------------------------------------- scenario
def test_paper_scenario_crossings_and_streams():
    """Reconstructed truth X0 = [3, 25, 120, 10, 5, 0]: crossings at 4.4 s (1-2), 11.7 s (1-3), 19.0 s (2-3);
    2001 states over 20 s; the first runs of a short Monte Carlo equal those of a long one; other seeds differ."""
    scn = st.paper_scenario(3)
    cross = scn.crossing_times()
    assert [(i, j) for i, j, _ in cross] == [(0, 1), (0, 2), (1, 2)]
    np.testing.assert_allclose([t for _, _, t in cross], [4.4, 11.7, 19.0], rtol=1e-12)
    truth = scn.truth()
    assert truth.shape == (2001, 6)
    np.testing.assert_allclose(truth[-1], [203.0, 125.0, 120.0, 10.0, 5.0, 0.0], rtol=1e-12)
    a, b = st.simulate(scn, 3, seed=4), st.simulate(scn, 5, seed=4)
    np.testing.assert_array_equal(a.z, b.z[:3])
    assert not np.allclose(st.simulate(scn, 3, seed=5).z, a.z)
    assert np.std(a.z - truth[None, 1:, :3]) == pytest.approx(5.0, rel=0.02)
    np.testing.assert_array_equal(a.symmetric("products"), SymmetricSensor("products", 3).transform(a.z))
    with pytest.raises(ValueError, match="p0_diag"):
        st.LineTargets(x0=(0.0, 1.0, 1.0, 0.0), p0_diag=(1.0, 1.0, 1.0))
    with pytest.raises(ValueError, match="n_targets"):
        SymmetricSensor("powers", 4)


# ----------------------------------------------------------------------------------------- the claims
def _claims(n_runs: int, seed: int):
    mc = s3.monte_carlo(st.paper_scenario(3), n_runs, seed)
    means = {f: [s3.window_mean(mc, f, i, 1.0, 20.0) for i in range(3)] for f in s3.FILTERS}
    return mc, means


def _assert_kf_lowest_and_kinks(mc, means):
    for f in FORMS:
        assert means[f][0] >= 1.05 * means["kf"][0], means
        assert s3.kink(mc, f, 0, 4.4)[0] >= 1.4, (f, s3.kink(mc, f, 0, 4.4))
        assert abs(s3.kink(mc, f, 0, 4.4)[1] - 4.4) <= 1.0
        assert not mc.diverged[f].any() and not mc.exchanges[f].any()


def test_paper_claims_on_a_reduced_monte_carlo():
    """Paper 003 Fig. 2 on 20 seeded runs (seed 0) of the paper's set-up with the default P0 [D]: the associated
    KF has the lowest mean RMSE of target 1 over 1-20 s (each EKF at least 5 % above it; measured KF 0.36 m,
    products 0.42 m, powers 0.48 m); the EKF/KF ratio peaks at least 1.4 within 1 s of the 4.4 s crossing
    (measured 2.2 and 3.3); no run diverges and no labelling changes after 1 s (the kinks are not label
    exchanges). Products vs powers is not asserted here (not robust at 20 runs, module docstring)."""
    mc, means = _claims(20, 0)
    _assert_kf_lowest_and_kinks(mc, means)


@pytest.mark.slow
@pytest.mark.skipif(not FULL, reason="100-run Monte Carlo: set ROADTRACK_FULL=1")
def test_paper_claims_on_100_runs():
    """As the reduced test on the paper's 100 runs, plus its ordering: mean RMSE 1-20 s of targets 1 and 2 with
    sum of products below sum of powers (seed 0 measured: target 1 0.413 vs 0.443 m, target 2 0.424 vs 0.444 m;
    seeds 1-4 alike). Target 3 (stationary) is not asserted: there the two forms are within 0.01 m."""
    mc, means = _claims(100, 0)
    _assert_kf_lowest_and_kinks(mc, means)
    assert means["products"][0] < means["powers"][0] and means["products"][1] < means["powers"][1], means
    assert math.isfinite(means["powers"][2])
