"""Per-detection measurement covariances (issue 29.4): a detection's own R_j in the gate, the likelihood, the
update and initiation of every built-in filter, the fixed R as the fallback."""

from __future__ import annotations

import numpy as np
import pytest

from roadtrack import trackers
from roadtrack.trackers.filters import make_filter
from roadtrack.trackers.filters.base import check_detection_R, takes_detection_R
from roadtrack.trackers.gating import mahalanobis2_and_log_gaussian
from roadtrack.trackers.state import FilterState

P_PRED = np.array([[1.0, 0.0, 0.5, 0.0], [0.0, 1.0, 0.0, 0.5], [0.5, 0.0, 1.0, 0.0], [0.0, 0.5, 0.0, 1.0]])
X_PRED = np.array([0.0, 0.0, 1.0, 0.0])


def test_one_detection_update_equals_the_hand_computed_case():
    """z = (1, 0.5), R_j = diag(0.25, 1): S = diag(1.25, 2), K = [[0.8, 0], [0, 0.5], [0.4, 0], [0, 0.25]], worked by
    hand; the fixed R (sigma_w = 0.3) gives another answer."""
    kf = make_filter("kf", sigma_w=0.3, detection_R=True)
    s = FilterState(x=X_PRED, P=P_PRED, e_post=np.zeros(2))
    R = np.diag([0.25, 1.0])[None]
    out = kf.update(s, np.array([[1.0, 0.5]]), np.array([1.0]), 0.0, R=R)
    np.testing.assert_allclose(out.x, [0.8, 0.25, 1.4, 0.125], atol=1e-12)
    np.testing.assert_allclose(out.P, [[0.2, 0.0, 0.1, 0.0], [0.0, 0.5, 0.0, 0.25], [0.1, 0.0, 0.8, 0.0],
                                       [0.0, 0.25, 0.0, 0.875]], atol=1e-12)
    fixed = kf.update(s, np.array([[1.0, 0.5]]), np.array([1.0]), 0.0)
    assert abs(fixed.x[0] - 1.0 / 1.09) < 1e-12 and abs(fixed.x[0] - out.x[0]) > 0.1


def _mixture(x, P, H, R, nu, beta, beta0):
    """The PDA posterior as the moments of the M + 1 hypotheses, each with its own Kalman update (a loop)."""
    means, covs, weights = [x], [P], [beta0]
    for nu_j, R_j, b in zip(nu, R, beta):
        S = H @ P @ H.T + R_j
        K = P @ H.T @ np.linalg.inv(S)
        means.append(x + K @ nu_j)
        covs.append(P - K @ S @ K.T)
        weights.append(b)
    mean = sum(w * m for w, m in zip(weights, means))
    cov = sum(w * (C + np.outer(m - mean, m - mean)) for w, m, C in zip(weights, means, covs))
    return mean, cov


@pytest.mark.parametrize("kind", ["kf", "ekf"])
def test_pda_update_is_the_mixture_of_per_detection_updates(kind):
    flt = make_filter(kind, sigma_w=0.3)
    s = FilterState(x=X_PRED, P=P_PRED, e_post=np.zeros(2))
    nu = np.array([[0.4, -0.3], [-1.0, 0.8], [0.2, 1.5]])
    R = np.array([np.diag([0.04, 0.5]), [[0.3, 0.1], [0.1, 0.2]], np.diag([1.0, 1.0])])
    beta, beta0 = np.array([0.5, 0.2, 0.1]), 0.2
    out = flt.update(s, nu, beta, beta0, R=R)
    H = flt.measurement.matrix(flt.motion)
    mean, cov = _mixture(X_PRED, P_PRED, H, R, nu, beta, beta0)
    np.testing.assert_allclose(out.x, mean, atol=1e-12)
    np.testing.assert_allclose(out.P, cov, atol=1e-12)
    # with every R_j the fixed R, the per-detection form is the thesis's (4.16)-(4.17) exactly
    same = flt.update(s, nu, beta, beta0, R=np.broadcast_to(flt.measurement.R, (3, 2, 2)))
    ref = flt.update(s, nu, beta, beta0)
    np.testing.assert_allclose(same.x, ref.x, atol=1e-12)
    np.testing.assert_allclose(same.P, ref.P, atol=1e-12)
    np.testing.assert_allclose(same.e_post, ref.e_post, atol=1e-12)


@pytest.mark.parametrize("kind", ["svsf", "gc-svsf", "gvbl-svsf"])
def test_svsf_family_uses_the_weighted_detection_covariance(kind):
    """The SVSF family's update takes the association-weighted mean of the detections' R ([D]): one detection with
    R_j equals the filter built with that noise (sigma_w^2 = R_j), and two weights combine their covariances."""
    flt = make_filter(kind, sigma_v=2.0, sigma_w=0.5)
    s = flt.predict(flt.initial_state(X_PRED, P_PRED), 0.1)
    nu = np.array([[0.3, -0.2]])
    own = flt.update(s, nu, np.array([1.0]), 0.0, R=np.array([0.04 * np.eye(2)]))
    built = make_filter(kind, sigma_v=2.0, sigma_w=0.2, **({"psi": 1.5} if kind == "svsf" else
                                                          {"psi_z": 1.5} if kind == "gc-svsf" else {}))
    ref = built.update(s, nu, np.array([1.0]), 0.0)
    fixed = flt.update(s, nu, np.array([1.0]), 0.0)
    np.testing.assert_allclose(own.P, ref.P, atol=1e-12)
    assert not np.allclose(own.P, fixed.P)
    two = flt.update(s, np.array([[0.3, -0.2], [0.1, 0.4]]), np.array([0.5, 0.5]), 0.0,
                     R=np.array([0.04 * np.eye(2), 0.36 * np.eye(2)]))
    mean_R = make_filter(kind, sigma_v=2.0, sigma_w=float(np.sqrt(0.2)),
                         **({"psi": 1.5} if kind == "svsf" else {"psi_z": 1.5} if kind == "gc-svsf" else {}))
    np.testing.assert_allclose(two.P, mean_R.update(s, np.array([[0.3, -0.2], [0.1, 0.4]]), np.array([0.5, 0.5]),
                                                    0.0).P, atol=1e-12)


def test_pair_distances_equal_one_covariance_per_pair():
    rng = np.random.default_rng(3)
    nu = rng.normal(size=(4, 5, 2))
    A = rng.normal(size=(4, 5, 2, 2))
    S = A @ np.swapaxes(A, -1, -2) + 0.1 * np.eye(2)
    d2, log_n = mahalanobis2_and_log_gaussian(nu, S)
    for t in range(4):
        for j in range(5):
            d, ln = mahalanobis2_and_log_gaussian(nu[t, j][None, None], S[t, j][None])
            assert abs(d2[t, j] - d[0, 0]) < 1e-10 and abs(log_n[t, j] - ln[0, 0]) < 1e-10


def _tracker(name="nn-kf", detection_R=True, **kw):
    return trackers.make_tracker(name, sigma_w=0.3, sigma_v=0.5, detection_R=detection_R, **kw)


def _confirmed_track(trk):
    """One confirmed track at the origin moving +x at 10 m/s (a few scans of clean detections)."""
    tracks, nid = (), 1
    for k in range(8):
        res = trk.step(tracks, np.array([[1.0 * k, 0.0]]), 0.1, nid)
        tracks, nid = res.tracks, res.next_id
    assert any(t.confirmed for t in tracks)
    return tracks, nid


def test_tracker_gates_and_scores_with_the_detection_covariance():
    """A detection 3 m off the prediction: outside the gate with the fixed R (sigma_w = 0.3 m), inside it when the
    detection says it is that uncertain (R_j = 4 I m^2); its NIS is computed with R_j."""
    trk = _tracker()
    tracks, nid = _confirmed_track(trk)
    z = np.array([[8.0, 3.0]])
    fixed = trk.step(tracks, z, 0.1, nid)
    own = trk.step(tracks, z, 0.1, nid, R=np.array([4.0 * np.eye(2)]))
    assert not fixed.info.gated.any() and own.info.gated[0, 0]
    rec = own.tracks[0].history[-1]
    S = own.info.S[0] - trk.filter.measurement.R + 4.0 * np.eye(2)
    assert abs(rec.nis - rec.nu_c @ np.linalg.solve(S, rec.nu_c)) < 1e-9
    # the switch (off by default): detection_R = false ignores the detections' covariances
    off = _tracker(detection_R=False)
    t_off, n_off = _confirmed_track(off)
    assert not off.step(t_off, z, 0.1, n_off, R=np.array([4.0 * np.eye(2)])).info.gated.any()
    assert not takes_detection_R(off.filter) and takes_detection_R(trk.filter)
    assert not takes_detection_R(trackers.make_tracker("jpda-kf").filter)


def test_a_new_track_starts_with_its_detections_covariance():
    trk = _tracker(management={"initiation": "single"})
    res = trk.step((), np.array([[5.0, 1.0]]), 0.1, 1, R=np.array([[[0.5, 0.1], [0.1, 0.2]]]))
    np.testing.assert_allclose(res.tracks[0].state.P[:2, :2], [[0.5, 0.1], [0.1, 0.2]])


@pytest.mark.parametrize("name", ["jpda-kf", "pda-svsf", "jpda-gvbl-svsf", "imm-pda-kf", "apda-svsf",
                                  "imm-jpda-gvbl-svsf"])
def test_named_trackers_run_with_detection_covariances(name):
    """Two crossing cars with range-dependent R and clutter: every scan runs, the tracks follow their cars."""
    trk = trackers.make_tracker(name, detection_R=True)
    assert takes_detection_R(trk.filter)
    rng = np.random.default_rng(0)
    tracks, nid = (), 1
    for k in range(40):
        cars = np.array([[20.0 + 1.0 * k, 3.0], [60.0 - 0.8 * k, -3.0]])
        std = 0.05 + 0.004 * np.hypot(*cars.T)  # range-aware, as perception's
        Z = cars + rng.normal(size=(2, 2)) * std[:, None]
        R = np.array([s * s * np.eye(2) for s in std])
        clutter = rng.uniform([0, -20], [100, 20], size=(2, 2))
        Z, R = np.vstack([Z, clutter]), np.vstack([R, np.array([0.01 * np.eye(2)] * 2)])
        res = trk.step(tracks, Z, 0.1, nid, R=R)
        tracks, nid = res.tracks, res.next_id
    kin, _ = trk.kinematics(tuple(t for t in tracks if t.confirmed))
    assert len(kin) >= 2
    for car in np.array([[59.0, 3.0], [28.8, -3.0]]):
        assert np.min(np.hypot(*(kin[:, :2] - car).T)) < 1.0


@pytest.mark.parametrize("bad, msg", [
    (np.full((1, 2, 2), np.nan), "not finite"),
    (np.array([[[1.0, 0.0], [0.0, -1.0]]]), "not positive definite"),
    (np.array([[[1.0, 0.5], [0.0, 1.0]]]), "symmetric"),
    (np.eye(2)[None].repeat(2, axis=0), r"\(1, 2, 2\)"),
])
def test_bad_detection_covariances_are_one_line_errors(bad, msg):
    trk = _tracker()
    with pytest.raises(ValueError, match=msg) as err:
        trk.step((), np.array([[1.0, 2.0]]), 0.1, 1, R=bad)
    assert "\n" not in str(err.value)
    with pytest.raises(ValueError, match=msg):
        check_detection_R(bad, 1, 2)
