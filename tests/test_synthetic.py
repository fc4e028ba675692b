"""The seeded single-target harness testbed.reproduce.thesis.synthetic: truth geometry, sensor statistics, stream independence,
the tracking loop and the metrics."""

import math

import numpy as np
import pytest
from scipy.stats import chi2

from roadtrack.testbed.reproduce.thesis import synthetic as sy
from roadtrack.trackers.filters import make_filter


def test_truth_segments_follow_their_models():
    """NCV without noise is a straight line; a CT arc keeps the speed and turns by omega * t; a_scale scales
    the whole transition; ts_scale only the Ts entries (thesis (3.74))."""
    dt, w = 0.5, 0.2
    scn = sy.Scenario(x0=(1.0, 2.0, 10.0, 0.0), segments=(sy.Segment(4, process_noise=False), sy.Segment(10, omega=w),
                      sy.Segment(1, a_scale=1.02, process_noise=False),
                      sy.Segment(1, ts_scale=1.5, process_noise=False)),
                      dt=dt, sigma_v=1.0, sigma_w=1.0)
    X = sy.simulate(scn, 0).truth
    np.testing.assert_allclose(X[4], [21.0, 2.0, 10.0, 0.0], rtol=0, atol=1e-12)
    np.testing.assert_allclose(np.hypot(X[14, 2], X[14, 3]), 10.0, rtol=0, atol=1e-12)
    np.testing.assert_allclose(math.atan2(X[14, 3], X[14, 2]), w * 10 * dt, rtol=0, atol=1e-12)
    A = np.eye(4) + dt * np.eye(4, k=2)
    np.testing.assert_allclose(X[15], 1.02 * A @ X[14], rtol=1e-14, atol=1e-12)
    np.testing.assert_allclose(X[16], (np.eye(4) + 1.5 * dt * np.eye(4, k=2)) @ X[15], rtol=1e-14, atol=1e-12)
    with pytest.raises(ValueError, match="ts_scale applies to NCV"):
        sy.Segment(3, omega=0.1, ts_scale=1.1)


def test_manoeuvre_shapes():
    """curve: heading change as asked; cut_in_out: back to the original heading with the asked peak lateral
    offset (3.5 m at 30 m/s over 40 s) and lane-change geometry +w, -w, +w."""
    dt, v = 0.1, 30.0
    segs = sy.from_timeline((0.0, 0.0, v, 0.0), dt, ((10, "ncv"), (30, "curve"), (40, "ncv"), (80, "cut_in_out")))
    scn = sy.Scenario(x0=(0.0, 0.0, v, 0.0), segments=segs, dt=dt, sigma_v=0.0, sigma_w=1.0)
    X = sy.simulate(scn, 1).truth
    heading = np.unwrap(np.arctan2(X[:, 3], X[:, 2]))
    np.testing.assert_allclose(heading[300] - heading[100], math.radians(10.0), rtol=0, atol=1e-9)
    k0 = 400
    np.testing.assert_allclose(heading[-1], heading[k0], rtol=0, atol=1e-9)
    d = np.array([-math.sin(heading[k0]), math.cos(heading[k0])])  # lateral axis at the start of the lane change
    lateral = (X[k0:, :2] - X[k0, :2]) @ d
    np.testing.assert_allclose(lateral.max(), 3.5, rtol=1e-3)
    np.testing.assert_allclose(lateral[-1], 0.0, atol=1e-6)
    with pytest.raises(ValueError, match="unknown timeline kind"):
        sy.from_timeline((0.0, 0.0, v, 0.0), dt, ((10, "loop"),))


def test_sensor_statistics_within_bounds():
    """Over 4000 scans: detection rate within 4 binomial sigmas of pd = 0.8; target measurement noise variance
    within the 99.9 % chi-square interval of sigma_w^2 = 4; clutter count within 4 Poisson sigmas of
    lambda (2 w)^2 per scan (lambda = 1e-3, w = 10 sigma_w = 20 m), uniform in the window."""
    K = 4000
    scn = sy.Scenario(x0=(0.0, 0.0, 5.0, 0.0), segments=(sy.Segment(K),), dt=0.1, sigma_v=0.5, sigma_w=2.0, pd=0.8,
                      clutter_density=1e-3)
    run = sy.simulate(scn, 2)
    det = np.array([o.any() for o in run.origin])
    assert abs(det.mean() - 0.8) < 4 * math.sqrt(0.8 * 0.2 / K)
    noise = np.array([z[o][0] - x[:2] for z, o, x in zip(run.Z, run.origin, run.truth[1:]) if o.any()])
    dof = noise.size
    assert chi2.ppf(0.0005, dof) < (noise ** 2).sum() / 4.0 < chi2.ppf(0.9995, dof)
    n_clutter = np.array([(~o).sum() for o in run.origin])
    mean = 1e-3 * 40.0 ** 2
    assert abs(n_clutter.sum() - mean * K) < 4 * math.sqrt(mean * K)
    offsets = np.vstack([z[~o] - x[:2] for z, o, x in zip(run.Z, run.origin, run.truth[1:])])
    assert np.abs(offsets).max() <= 20.0 and abs(offsets.mean()) < 0.5


def test_random_streams_are_independent_and_seeded():
    """Same seed, same run; adding clutter or lowering pd changes neither the truth nor the target's noise."""
    base = dict(x0=(0.0, 0.0, 5.0, 1.0), segments=(sy.Segment(50),), dt=0.5, sigma_v=0.5, sigma_w=1.0)
    a = sy.simulate(sy.Scenario(**base), 3)
    b = sy.simulate(sy.Scenario(**base), 3)
    c = sy.simulate(sy.Scenario(**base, clutter_density=1e-2), 3)
    np.testing.assert_array_equal(a.truth, b.truth)
    np.testing.assert_array_equal(np.vstack(a.Z), np.vstack(b.Z))
    np.testing.assert_array_equal(c.truth, a.truth)
    np.testing.assert_array_equal(np.vstack([z[o] for z, o in zip(c.Z, c.origin)]), np.vstack(a.Z))
    assert sum(len(z) for z in c.Z) > sum(len(z) for z in a.Z)
    d = sy.simulate(sy.Scenario(**base, pd=0.5), 3)
    kept = [k for k, o in enumerate(d.origin) if o.any()]
    np.testing.assert_array_equal(np.vstack([d.Z[k][:1] for k in kept]), np.vstack([a.Z[k] for k in kept]))
    e = sy.simulate(sy.Scenario(**base, perturb_init=True), 3)
    assert np.abs(e.x0_est - a.x0_est).max() > 0 and np.array_equal(a.x0_est, np.array(base["x0"]))


def test_lost_at():
    err = np.array([1, 2, 50, 1, 60, 70, 80, 90, 95.0])
    assert sy.lost_at(err, 10.0) == 4
    assert sy.lost_at(err, 10.0, min_steps=6) is None
    assert sy.lost_at(np.ones(9), 10.0) is None
    assert sy.lost_at(np.full(9, 20.0), 10.0) == 0


def test_track_kf_matches_its_own_covariance_on_clean_ncv():
    """A matched KF on clean NCV data through the harness (nearest-neighbour association, pd = 1, no clutter,
    a wide gate so that every scan updates):
    the time-averaged NEES over 20 runs x 200 scans lies in the 99.9 % chi-square interval for 4 states."""
    scn = sy.Scenario(x0=(0.0, 0.0, 10.0, -3.0), segments=(sy.Segment(200),), dt=0.5, sigma_v=0.5, sigma_w=3.0)
    kf = make_filter("kf", sigma_v=0.5, sigma_w=3.0)
    nees = []
    for ss in np.random.SeedSequence(4).spawn(20):
        run = sy.simulate(scn, ss)
        est = sy.track(run, scn, kf, associator="nn", association={"gate_alpha": 100.0})
        e = est.x - run.truth
        nees.append(np.einsum("ki,kij,kj->k", e[1:], np.linalg.inv(est.P[1:]), e[1:]))
        assert est.n_gated.min() == 1 and est.w0.max() == 0.0
    n = np.size(nees)
    assert chi2.ppf(0.0005, 4 * n) / n < np.mean(nees) < chi2.ppf(0.9995, 4 * n) / n


def test_monte_carlo_shapes_metrics_and_info():
    scn = sy.Scenario(x0=(0.0, 0.0, 10.0, 0.0), segments=(sy.Segment(30),), dt=0.5, sigma_v=0.5, sigma_w=3.0,
                      pd=0.9, clutter_density=1e-3)
    out = sy.monte_carlo(scn, {"kf": make_filter("kf", sigma_v=0.5, sigma_w=3.0),
                               "gvbl": make_filter("gvbl-svsf", sigma_v=0.5, sigma_w=3.0)}, 3, 5)
    kf, gv = out["kf"], out["gvbl"]
    assert kf.errors.shape == (3, 31, 4) and gv.info["psi_z"].shape == (3, 30, 2)
    assert gv.info["regime"].shape == (3, 30, 1)
    np.testing.assert_allclose(kf.rmse(), np.sqrt((kf.errors[:, 1:] ** 2).mean(axis=(0, 1))), rtol=1e-15)
    np.testing.assert_array_equal(kf.errors[:, 0], 0.0)  # known initial state
    assert kf.lost(1e6).sum() == 0 and kf.lost(0.0).sum() == 3
    assert kf.info == {}
