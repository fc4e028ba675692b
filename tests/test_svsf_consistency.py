"""Consistency of the fixed-layer SVSFs (`svsf`, `gc-svsf`) on well-detected targets (issue 17, point 4).

Cause pinned here: inside the boundary layer the SVSF gain is |e| / psi (thesis (2.10), (4.29)), a function of
the innovation and not of P. The Joseph form (2.12)/(4.37) is the covariance of a gain that does NOT depend on
e (its average over e ~ N(0, S)); with a small gain it barely contracts P, which then grows with Q alone, so the
better a target is measured the larger its gate. The default covariance "mse" is the mean-square error about
the SVSF estimate given the innovations (`estimate_mse`): the KF's P when the SVSF estimate equals the KF's,
plus the squared distance between the two. The shipped scenarios' filter: dt = 0.1 s, sigma_v = 4 m/s^2,
sigma_w = 0.5 m, layer psi = 0.2 m (scenarios/*.toml) or the default 3 sigma_w = 1.5 m."""

import numpy as np
import pytest
from scipy.stats import chi2

from roadtrack.trackers import make_tracker
from roadtrack.trackers.filters import make_filter
from roadtrack.trackers.filters.svsf import estimate_mse, generalised_covariance
from roadtrack.trackers.filters.base import pda_covariance
from roadtrack.trackers.models import ConstantVelocity

DT, SV, SW = 0.1, 4.0, 0.5
N_RUNS, N_STEPS = 50, 100
X0 = np.array([0.0, 0.0, 22.0, 0.0])
P0 = np.diag([SW ** 2, SW ** 2, 4.0, 4.0])
CASES = {"svsf-psi0.2": ("svsf", {"psi": 0.2}), "svsf-3sigma": ("svsf", {}),
         "gc-svsf-psi0.2": ("gc-svsf", {"psi_z": 0.2}), "gc-svsf-3sigma": ("gc-svsf", {})}


def monte_carlo(flt, seed: int, sigma_v: float = SV, sigma_w: float = SW, n_runs: int = N_RUNS,
                n_steps: int = N_STEPS) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(NEES (runs, steps), position NEES (runs, steps), sqrt|S| (runs, steps) [m^2]) of `flt` on NCV truth with
    white acceleration sigma_v [m/s^2], x0 ~ N(X0, P0), positions measured every scan with sigma_w [m] (no
    clutter, no miss: hard association)."""
    motion = ConstantVelocity(sigma_v)
    A, G, L0 = motion.transition(DT), sigma_v * motion.noise_gain(DT), np.linalg.cholesky(P0)
    rng = np.random.default_rng(seed)
    nees, nees_p, sdet = (np.empty((n_runs, n_steps)) for _ in range(3))
    for r in range(n_runs):
        x = X0 + L0 @ rng.normal(size=4)
        s = flt.initial_state(X0, P0)
        for k in range(n_steps):
            x = A @ x + G @ rng.normal(size=2)
            sp = flt.predict(s, DT)
            z_hat, S = flt.predicted_measurement(sp)
            s = flt.update(sp, (x[:2] + sigma_w * rng.normal(size=2) - z_hat)[None], np.ones(1), 0.0)
            e = s.x - x
            nees[r, k] = e @ np.linalg.solve(s.P, e)
            nees_p[r, k] = e[:2] @ np.linalg.solve(s.P[:2, :2], e[:2])
            sdet[r, k] = np.sqrt(np.linalg.det(S))
    return nees, nees_p, sdet


def band_fraction(values: np.ndarray, dof: int) -> tuple[float, float, float, float]:
    """(fraction of scans whose run-average is inside the two-sided 95 % chi-square band, mean over scans,
    band low, band high): N * ANEES ~ chi2(N dof) per scan."""
    n = values.shape[0]
    lo, hi = chi2.ppf([0.025, 0.975], n * dof) / n
    per_scan = values.mean(axis=0)
    return float(np.mean((per_scan >= lo) & (per_scan <= hi))), float(per_scan.mean()), lo, hi


@pytest.mark.parametrize("case", sorted(CASES))
def test_fixed_layer_svsf_nees_within_chi_square_band(case):
    """50 seeded runs x 100 scans on the filter's own model. Per scan, the run-averaged NEES (4 dof) and position
    NEES (2 dof) inside the two-sided 95 % band on >= 85 % of scans (expected 95 %; the KF: 0.95 / 0.96), their
    means over scans inside it. Measured, in-band fraction NEES / position NEES, mse (default) vs joseph:
    svsf psi 0.2 m 0.99 / 0.96 vs 0.50 / 0.93; svsf 3 sigma 0.91 / 0.96 vs 0.85 / 0.41 (position NEES mean
    1.46 below the band's 1.48); gc-svsf psi 0.2 m 0.96 / 0.98 vs 0.81 / 0.94; gc-svsf 3 sigma 0.99 / 0.94 vs
    0.95 / 0.80. sqrt|S| (median): KF 0.37 m^2, mse SVSFs 0.70-1.04 (their estimates are worse than the KF's)."""
    kind, params = CASES[case]
    nees, nees_p, _ = monte_carlo(make_filter(kind, sigma_v=SV, sigma_w=SW, **params), seed=17)
    for values, dof in ((nees, 4), (nees_p, 2)):
        inside, mean, lo, hi = band_fraction(values, dof)
        assert inside >= 0.85 and lo <= mean <= hi, (case, dof, inside, mean, lo, hi)


@pytest.mark.parametrize("case,dof,inside_max", [("svsf-psi0.2", 4, 0.6), ("svsf-3sigma", 2, 0.6),
                                                 ("gc-svsf-psi0.2", 4, 0.85), ("gc-svsf-3sigma", 2, 0.85)])
def test_joseph_form_fails_the_same_band(case, dof, inside_max):
    """The literal (2.12)/(4.37) covariance (kept as covariance = "joseph") on the same runs fails the criterion
    above (numbers in its docstring): the standard SVSF clearly, the generalised SVSF narrowly."""
    kind, params = CASES[case]
    nees, nees_p, _ = monte_carlo(make_filter(kind, sigma_v=SV, sigma_w=SW, covariance="joseph", **params), seed=17)
    inside, mean, lo, hi = band_fraction(nees if dof == 4 else nees_p, dof)
    assert inside < inside_max, (case, inside, mean, lo, hi)


# ------------------------------------------------------------------------------------------ the cause
def test_zero_innovations_joseph_grows_with_q_alone_mse_is_the_kalman_filter():
    """A noise-free CV target measured exactly: every innovation is 0, so the SVSF gain (|e| + gamma |e_post|)
    / psi is 0 and the Joseph P* is the prediction: P grows with Q without bound (the issue's gates). The mse
    covariance is then the KF's P exactly (to 1e-9 relative), whose gate stays at the KF's steady state."""
    kf = make_filter("kf", sigma_v=SV, sigma_w=SW)
    for kind, params in CASES.values():
        flts = {c: make_filter(kind, sigma_v=SV, sigma_w=SW, covariance=c, **params) for c in ("joseph", "mse")}
        states = {c: f.initial_state(X0, P0) for c, f in flts.items()}
        sk, x, P_open = kf.initial_state(X0, P0), X0.copy(), P0.copy()
        for _ in range(200):
            x = flts["mse"].motion.f(x, DT)
            P_open = flts["mse"].motion.transition(DT) @ P_open @ flts["mse"].motion.transition(DT).T \
                + flts["mse"].motion.process_noise(DT, x)
            for c, f in flts.items():
                sp = f.predict(states[c], DT)
                states[c] = f.update(sp, (x[:2] - f.predicted_measurement(sp)[0])[None], np.ones(1), 0.0)
            sp = kf.predict(sk, DT)
            sk = kf.update(sp, (x[:2] - kf.predicted_measurement(sp)[0])[None], np.ones(1), 0.0)
        np.testing.assert_allclose(states["joseph"].P, P_open, rtol=1e-9)  # no contraction at all
        np.testing.assert_allclose(states["mse"].P, sk.P, rtol=1e-9)
        assert np.trace(states["joseph"].P[:2, :2]) > 1e4 * np.trace(sk.P[:2, :2])  # 20 s: ~ sigma_v^2 t^3 / 3


def test_estimate_mse_identities():
    """estimate_mse: (a) x = Kalman estimate -> the PDA covariance (4.16)-(4.17) with P* = P_kf (1e-12);
    (b) one measurement, any gain K: P_kf + (K - K_kf) e e^T (K - K_kf)^T, and the same expression with e e^T
    replaced by S is the generalised / Joseph covariance (4.37) (1e-12): (4.37) is its average for a fixed gain."""
    rng = np.random.default_rng(5)
    n, m = 4, 2
    L = rng.normal(size=(n, n))
    P = L @ L.T + np.eye(n)
    H, R = np.eye(m, n), 0.25 * np.eye(m)
    S = H @ P @ H.T + R
    K_kf = P @ H.T @ np.linalg.inv(S)
    P_kf = P - K_kf @ S @ K_kf.T
    x_pred = rng.normal(size=n)
    nu, beta = rng.normal(size=(3, m)), np.array([0.5, 0.2, 0.1])
    got = estimate_mse(P, H, R, x_pred, x_pred + K_kf @ (beta @ nu), nu, beta, 0.2)
    np.testing.assert_allclose(got, pda_covariance(P, P_kf, K_kf, nu, beta, 0.2), rtol=1e-12, atol=1e-12)
    K, e = rng.normal(size=(n, m)), rng.normal(size=m)
    got = estimate_mse(P, H, R, x_pred, x_pred + K @ e, e[None], np.ones(1), 0.0)
    D = K - K_kf
    np.testing.assert_allclose(got, P_kf + D @ np.outer(e, e) @ D.T, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(P_kf + D @ S @ D.T, generalised_covariance(P, K, H, S), rtol=1e-12, atol=1e-12)


def test_well_detected_target_gate_stays_at_the_kalman_filters():
    """LiDAR-like: a car at constant speed whose detected centre moves 2 cm between frames (the convoy's
    innovations, NIS ~ 1e-4), 3 runs of 20 s. sqrt|S| of the mse SVSFs within 5 % of the KF's from 5 s on
    (measured: 1.9 % at most); with the Joseph form the standard SVSF's grows all run (measured at 20 s:
    5.5-7.5 m^2 for psi 0.2 m, 39-87 m^2 for 3 sigma, against the KF's 0.37; gc-svsf 0.9-1.0 and 3.4-5.7)."""
    kf = monte_carlo(make_filter("kf", sigma_v=SV, sigma_w=SW), 3, 0.0, 0.02, n_runs=3, n_steps=200)[2]
    for kind, params in CASES.values():
        s = monte_carlo(make_filter(kind, sigma_v=SV, sigma_w=SW, **params), 3, 0.0, 0.02, n_runs=3, n_steps=200)[2]
        assert np.all(np.abs(s[:, 50:] / kf[:, 50:] - 1.0) < 0.05), (kind, params, s[:, -1], kf[:, -1])
    joseph = monte_carlo(make_filter("svsf", sigma_v=SV, sigma_w=SW, psi=0.2, covariance="joseph"), 3, 0.0, 0.02,
                         n_runs=3, n_steps=200)[2]
    assert np.all(joseph[:, -1] > 10.0 * kf[:, -1]) and np.all(joseph[:, -1] > joseph[:, 100]), joseph[:, -1]


@pytest.mark.parametrize("layer", [{"psi": 0.2}, {}], ids=["psi0.2", "3sigma"])
def test_jpda_svsf_convoy_gates_stay_small_and_every_car_keeps_its_track(layer):
    """Three cars 15 m apart in one lane at 22 m/s, detected every frame with 0.05 m noise, 15 s, jpda-svsf with
    the shipped scenarios' filter: after 2 s the largest gate stays within 1.5x of jpda-kf's and the first three
    labels survive to the end. Measured: jpda-kf 18.8 m^2; jpda-svsf 19.9 (psi 0.2 m) and 19.1 m^2 (3 sigma);
    with covariance = "joseph" 308 m^2 (psi 0.2 m) and 8,630 m^2 (3 sigma, every label lost, next id 11)."""
    rng = np.random.default_rng(11)
    cars = np.array([[0.0, 4.0], [15.0, 4.0], [30.0, 4.0]])
    Z = [cars + [22.0 * DT * k, 0.0] + 0.05 * rng.normal(size=cars.shape) for k in range(150)]
    worst = {}
    for name, filt in (("jpda-kf", {}), ("jpda-svsf", {"svsf": layer})):
        trk = make_tracker(name, filter={"sigma_v": SV, "sigma_w": SW, **filt})
        tracks, nid, vol = (), 0, []
        for z in Z:
            res = trk.step(tracks, z, DT, nid)
            tracks, nid = res.tracks, res.next_id
            vol.append(float(np.max(res.info.diagnostics.get("gate_volume", np.zeros(0)), initial=0.0)))
        worst[name] = max(vol[20:])
        assert sorted(t.id for t in tracks if t.confirmed) == [0, 1, 2], (name, [t.id for t in tracks])
    assert worst["jpda-svsf"] <= 1.5 * worst["jpda-kf"], worst
