"""IMM filter (thesis §2.3.4 (2.101)-(2.104), (1.17)-(1.18)): reduction to its mode filter,
hand-computed mixing of a 4-D + 5-D bank, the PDA mode-likelihood identity, a manoeuvre, a tracker run,
parameter errors."""

from contextlib import ExitStack
from dataclasses import replace
from unittest import mock

import numpy as np
import pytest

from roadtrack.trackers import CoordinatedTurn, ParamError, make_filter, make_tracker, pda, preset
from roadtrack.trackers.association.params import AssociationParams
from roadtrack.trackers.errors import FilterError
from roadtrack.trackers.filters.imm import IMMFilter, IMMState
from roadtrack.trackers.gating import log_gaussian
from roadtrack.trackers.registry import WRAPPERS
from state_fields import state_fields

X0 = np.array([10.0, -5.0, 20.0, 1.0])
P0 = np.diag([1.0, 1.0, 4.0, 4.0])


def random_cycle(rng, flt, s, dt):
    """One predict/update with a random association: a miss, a hard association or PDA weights over 3."""
    sp = flt.predict(s, dt)
    z_hat, S = flt.predicted_measurement(sp)
    L = np.linalg.cholesky(S)
    kind = rng.integers(3)
    if kind == 0:
        return sp, flt.update(sp, np.zeros((0, 2)), np.zeros(0), 1.0)
    M = 1 if kind == 1 else 3
    nu = (L @ rng.normal(size=(2, M))).T * rng.uniform(0.5, 2.0)
    w = np.array([1.0]) if M == 1 else rng.dirichlet(np.ones(M + 1))
    beta0 = 0.0 if M == 1 else float(w[0])
    return sp, flt.update(sp, nu, w if M == 1 else w[1:], beta0)


@pytest.mark.parametrize("mode,r", [({"kind": "kf", "motion": "cv"}, 3), ({"kind": "ekf", "motion": "ct"}, 2)])
def test_imm_of_identical_modes_equals_its_mode_filter(mode, r):
    """r identical modes and any Markov matrix: every mixed state, mode likelihood and output equals the mode
    filter's (to 1e-9 relative), over 200 seeded cycles with misses, hard and PDA updates."""
    rng = np.random.default_rng(7)
    Pi = rng.dirichlet(np.ones(r), size=r)
    imm = make_filter("imm", modes=(mode,) * r, transition=Pi.tolist(), mu0=rng.dirichlet(np.ones(r)).tolist())
    one = make_filter(mode["kind"], **{k: v for k, v in mode.items() if k != "kind"})
    s_imm, s_one = imm.initial_state(X0, P0), one.initial_state(X0, P0)
    rng_a, rng_b = np.random.default_rng(11), np.random.default_rng(11)
    for _ in range(200):
        dt = 0.1
        sp_imm, s_imm = random_cycle(rng_a, imm, s_imm, dt)
        sp_one, s_one = random_cycle(rng_b, one, s_one, dt)
        for a, b in ((sp_imm, sp_one), (s_imm, s_one)):
            scale = np.abs(b.P).max()
            np.testing.assert_allclose(a.x, b.x, rtol=1e-9, atol=1e-9 * np.abs(b.x).max())
            np.testing.assert_allclose(a.P, b.P, rtol=1e-9, atol=1e-9 * scale)
            np.testing.assert_allclose(a.e_post, b.e_post, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(s_imm.mu.sum(), 1.0, atol=1e-12)


def test_mixing_of_a_4d_cv_and_5d_ct_bank_matches_the_hand_formula():
    """(2.101)-(2.102) with padding (omega = 0, variance omega_std0^2) and dropping ([D]), and the
    5-D output combination (1.17)-(1.18): a zero-dt predict leaves the mixed states unchanged (A = I, Q = 0)."""
    rng = np.random.default_rng(3)
    imm = make_filter("imm", modes=({"kind": "kf"}, {"kind": "ekf", "motion": "ct", "omega_std0": 0.3}),
                      transition=[[0.8, 0.2], [0.3, 0.7]], mu0=[0.6, 0.4])
    A = rng.normal(size=(4, 4))
    B = rng.normal(size=(5, 5))
    x1, P1 = rng.normal(size=4), A @ A.T + np.eye(4)
    x2, P2 = rng.normal(size=5), B @ B.T + np.eye(5)
    e1, e2 = rng.normal(size=2), rng.normal(size=2)
    s0 = imm.initial_state(X0, P0)
    modes = (replace(s0.modes[0], x=x1, P=P1, e_post=e1), replace(s0.modes[1], x=x2, P=P2, e_post=e2))
    mu = np.array([0.25, 0.75])
    s = IMMState(x=x2, P=P2, e_post=e1, modes=modes, mu=mu)
    sp = imm.predict(s, 0.0)
    Pi = np.array([[0.8, 0.2], [0.3, 0.7]])
    c = Pi.T @ mu  # (2.101)
    np.testing.assert_allclose(sp.mu, c, rtol=1e-14)
    x1p, P1p = np.append(x1, 0.0), np.zeros((5, 5))  # CV padded into CT
    P1p[:4, :4], P1p[4, 4] = P1, 0.3**2
    for i, (xs, Ps) in enumerate([((x1, x2[:4]), (P1, P2[:4, :4])), ((x1p, x2), (P1p, P2))]):
        w = Pi[:, i] * mu / c[i]
        xm = w[0] * xs[0] + w[1] * xs[1]
        Pm = sum(w[j] * (Ps[j] + np.outer(xs[j] - xm, xs[j] - xm)) for j in range(2))
        np.testing.assert_allclose(sp.modes[i].x, xm, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(sp.modes[i].P, Pm, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(sp.modes[i].e_post, w[0] * e1 + w[1] * e2, rtol=1e-12, atol=1e-14)
    xo = c[0] * np.append(sp.modes[0].x, 0.0) + c[1] * sp.modes[1].x  # (1.17) in the 5-D layout
    Po = sum(c[j] * (Pj + np.outer(xj - xo, xj - xo)) for j, (xj, Pj) in
             enumerate([(np.append(sp.modes[0].x, 0.0), np.pad(sp.modes[0].P, (0, 1)) + np.diag([0, 0, 0, 0, 0.09])),
                        (sp.modes[1].x, sp.modes[1].P)]))
    np.testing.assert_allclose(sp.x, xo, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(sp.P, Po, rtol=1e-12, atol=1e-12)
    assert imm.output(sp)[0].shape == (5,) and imm.mode_names == ("cv", "ct")
    np.testing.assert_array_equal(sp.info["mu"], sp.mu)


def test_mode_likelihood_from_pda_weights_equals_thesis_form():
    """With PDA weights from the combined prediction, mu equals (2.103)-(2.104) computed directly,
    Lambda_i = lambda (1 - P_D P_G) + P_D sum_j N(z_j; z_i, S_i), to 1e-12; hard association gives N_i c_i."""
    rng = np.random.default_rng(5)
    imm = make_filter("imm", sigma_v=0.5, sigma_w=0.5)
    s = imm.initial_state(X0, 0.1 * np.eye(4))
    ct = replace(s.modes[1], x=np.append(X0, 0.2))  # the CT mode turns at 0.2 rad/s: the predictions differ by 2 m
    sp = imm.predict(replace(s, modes=(s.modes[0], ct), mu=np.array([0.5, 0.5])), 1.0)
    z_c, S_c = imm.predicted_measurement(sp)
    zs, Ss = imm.mode_measurements(sp)
    Z = np.vstack([zs[1] + 0.1 * rng.normal(size=2), z_c + rng.normal(size=(3, 2)) * 1.0])  # target on the CT path
    nu = Z - z_c
    p = AssociationParams(pd=0.9, pg=0.99, clutter_density=2e-3)
    W, w0 = pda(log_gaussian(nu[None], S_c[None]), np.ones((1, 4), dtype=bool), p)
    post = imm.update(sp, nu, W[0], float(w0[0]))
    n_i = np.exp(log_gaussian(Z[None] - zs[:, None], Ss))  # (2, 4): N(z_j; z_i, S_i)
    lam = p.clutter_density * (1 - p.pd * p.pg) + p.pd * n_i.sum(axis=1)  # (2.103)
    mu_ref = lam * sp.mu / (lam * sp.mu).sum()  # (2.104)
    assert abs(mu_ref[0] - sp.mu[0]) > 0.05  # the measurements do discriminate the modes here
    np.testing.assert_allclose(post.mu, mu_ref, rtol=1e-12)
    np.testing.assert_allclose(post.info["mu"], mu_ref, rtol=1e-12)
    hard = imm.update(sp, nu[:1], np.ones(1), 0.0)
    n = np.array([np.exp(log_gaussian((Z[:1] - zs[i])[None], Ss[i][None])[0, 0]) for i in range(2)])
    np.testing.assert_allclose(hard.mu, n * sp.mu / (n * sp.mu).sum(), rtol=1e-12)


def test_missed_scan_returns_the_prediction_with_predicted_mode_probabilities():
    imm = make_filter("imm")
    sp = imm.predict(imm.initial_state(X0, P0), 0.1)
    assert imm.update(sp, np.zeros((0, 2)), np.zeros(0), 1.0) is sp
    np.testing.assert_allclose(sp.mu, imm.transition.T @ imm.mu0, rtol=1e-14)  # (2.101) c = Pi^T mu
    np.testing.assert_array_equal(sp.info["mu"], sp.mu)


def test_missed_scan_resets_the_svsf_mode_memories_when_the_modes_say_so():
    """imm-pda-svsf with memory_after_miss = "reset" in its svsf (CV) and gvbl-svsf (CT) mode tables: a missed scan
    returns the prediction (x, P, mu unchanged) with every mode memory and the combined e_post at 0; with the
    default "keep" it is the prediction itself."""
    for mode in ("keep", "reset"):
        table = {"memory_after_miss": mode}
        imm = make_tracker("imm-pda-svsf", filter={"svsf": table, "gvbl-svsf": table}, sigma_w=1.0).filter
        sp = imm.predict(imm.initial_state(X0, P0), 0.1)
        s = imm.update(sp, np.array([[1.5, -0.5]]), np.ones(1), 0.0)
        sp = imm.predict(s, 0.1)
        assert all(np.abs(m.e_post).max() > 0.1 for m in sp.modes)
        out = imm.update(sp, np.zeros((0, 2)), np.zeros(0), 1.0)
        if mode == "keep":
            assert out is sp
            continue
        for m in out.modes:
            np.testing.assert_array_equal(m.e_post, 0.0)
        np.testing.assert_array_equal(out.e_post, 0.0)
        np.testing.assert_array_equal(out.mu, sp.mu)
        np.testing.assert_allclose(out.x, sp.x, rtol=0, atol=1e-14)
        np.testing.assert_allclose(out.P, sp.P, rtol=0, atol=1e-14)


# ----------------------------------------------------------------------------------------- manoeuvre
DT_M, SPEED, OMEGA = 0.5, 20.0, 0.2
STRAIGHT, TURN = 40, 16


def manoeuvre_run(seed, sigma_v=0.5, sigma_w=1.0):
    """Truth: NCV at 20 m/s for 40 scans, a known turn omega = 0.2 rad/s for 16 scans (4 m/s^2), NCV for 30
    (thesis §1.3 [R]: the 4x4 block of A_CT(omega)); positions measured with sigma_w; hard association."""
    rng_t, rng_z = [np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(2)]
    x, turn = np.array([0.0, 0.0, SPEED, 0.0]), CoordinatedTurn(0.0)
    imm = make_filter("imm", sigma_v=sigma_v, sigma_w=sigma_w)
    s = imm.initial_state(x, np.diag([sigma_w**2, sigma_w**2, 1.0, 1.0]))
    mu_ct, omega = [], []
    for k in range(STRAIGHT + TURN + 30):
        w = OMEGA if STRAIGHT <= k < STRAIGHT + TURN else 0.0
        x = turn.transition(DT_M, w)[:4, :4] @ x + 0.05 * rng_t.normal(size=4) * [DT_M**2 / 2, DT_M**2 / 2, DT_M, DT_M]
        sp = imm.predict(s, DT_M)
        z_hat, _ = imm.predicted_measurement(sp)
        s = imm.update(sp, (x[:2] + sigma_w * rng_z.normal(size=2) - z_hat)[None], np.ones(1), 0.0)
        mu_ct.append(s.mu[1])
        omega.append(s.x[4])
    return np.array(mu_ct), np.array(omega)


def test_ct_probability_rises_during_a_known_turn():
    """Seeds 0-4 (measured: straight mean mu_CT 0.17-0.25, turn 0.87-0.92, late-turn omega 0.17-0.19 rad/s):
    mu_CT <= 0.3 on the straight (scans 10-39), >= 0.8 in the turn (scans 42-55), rising by >= 0.5 in every
    seed; the combined turn-rate estimate over the second half of the turn is 0.2 +- 0.04 rad/s."""
    straight, turning, late_omega = [], [], []
    for seed in range(5):
        mu, om = manoeuvre_run(seed)
        straight.append(mu[10:STRAIGHT].mean())
        turning.append(mu[STRAIGHT + 2:STRAIGHT + TURN].mean())
        late_omega.append(om[STRAIGHT + TURN // 2:STRAIGHT + TURN].mean())
        assert turning[-1] - straight[-1] >= 0.5, (seed, straight[-1], turning[-1])
    assert np.mean(straight) <= 0.3 and np.mean(turning) >= 0.8, (straight, turning)
    np.testing.assert_allclose(np.mean(late_omega), OMEGA, atol=0.04)


# ------------------------------------------------------------------------------------------ tracker
DT = 0.1


def two_targets(seed, n=100):
    """Two NCV cars 3.5 m apart at 25 m/s, 10 Hz, clutter 1e-3 m^-2: the generator of the tracker tests."""
    from test_trackers_tracker import two_targets as parallel_pair  # tests/ is on sys.path (rootdir conftest)

    return parallel_pair(seed, "parallel", n=n)


def test_imm_pda_kf_tracker_follows_two_targets():
    """make_tracker("imm-pda-kf"): a 4-D KF-CV mode beside a 5-D EKF-CT mode. Seeds 0-2 (measured: both
    covered from scan 4-7, coverage 1.0, RMSE 0.23-0.27 m): both targets covered by 5-D confirmed tracks by
    scan 10, then in >= 95% of target-scans with position RMSE <= 0.4 m; the mode probabilities are logged
    per track as mu_0 (cv) and mu_1 (ct) and sum to 1."""
    tracker = make_tracker("imm-pda-kf", clutter_density=1e-3)
    assert tracker.filter.mode_names == ("cv", "ct")
    assert [f.motion.ndim for f in tracker.filter.filters] == [4, 5]
    for seed in range(3):
        X, Zs = two_targets(seed)
        tracks, nid, err, first = (), 0, np.full((len(Zs), 2), np.nan), None
        for k, Z in enumerate(Zs):
            r = tracker.step(tracks, Z, DT, nid)
            tracks, nid = r.tracks, r.next_id
            conf = [t for t in tracks if t.confirmed]
            for i in range(2):
                d = [np.linalg.norm(t.state.x[:2] - X[k, i, :2]) for t in conf]
                if d and min(d) < 2.0:
                    err[k, i] = min(d)
            if first is None and np.isfinite(err[k]).all():
                first = k
            d = r.info.diagnostics
            if "mu_0" in d:
                np.testing.assert_allclose(d["mu_0"] + d["mu_1"], 1.0, atol=1e-12)
        assert first is not None and first <= 10, (seed, first)
        assert all(t.state.x.shape == (5,) for t in tracks if not t.candidate)
        after = err[first:]
        assert np.mean(np.isfinite(after)) >= 0.95, seed
        assert np.sqrt(np.nanmean(after**2)) <= 0.4, seed


def test_wrapper_builds_a_cv_and_a_ct_mode_and_broadcasts_shared_noise():
    assert preset("imm-pda-kf")["filter"] == {"kind": "imm", "modes": ({"kind": "kf", "motion": "cv"},
                                                                      {"kind": "ekf", "motion": "ct"})}
    assert WRAPPERS["imm"]("ekf")[1]["modes"][1] == {"kind": "ekf", "motion": "ct"}
    assert WRAPPERS["imm"]("svsf")[1]["modes"] == ({"kind": "svsf", "motion": "cv"},
                                                  {"kind": "gvbl-svsf", "motion": "ct"})  # svsf cannot run CT
    assert WRAPPERS["imm"]("gc-svsf")[1]["modes"][1] == {"kind": "gvbl-svsf", "motion": "ct"}  # nor can gc-svsf
    for name in ("imm-pda-svsf", "imm-jpda-gc-svsf"):
        make_tracker(name)  # builds
    assert WRAPPERS["imm"]("gvbl-svsf")[1]["modes"][1] == {"kind": "gvbl-svsf", "motion": "ct"}
    tracker = make_tracker("imm-pda-kf", sigma_v=1.5, sigma_w=0.7)  # a scenario's shared keys reach every mode
    for f in tracker.filter.filters:
        assert f.motion.sigma_v == 1.5 and f.measurement.sigma_w == 0.7
    own = make_tracker("imm-pda-kf", filter={"sigma_v": 1.5, "modes": ({"kind": "kf"}, {"kind": "ekf", "motion": "ct",
                                                                                       "sigma_v": 4.0})})
    assert [f.motion.sigma_v for f in own.filter.filters] == [1.5, 4.0]  # a mode's own value wins


@pytest.mark.parametrize("table,message", [
    ({"modes": ({"kind": "kf"}, {"kind": "ekf", "motion": "ct", "sigma_v": "x"})},
     "filter.modes[1].sigma_v: expected a finite number, got 'x'"),
    ({"modes": ({"kind": "kf"}, {"kind": "ekf", "sigma_v": -1.0})}, "filter.modes[1].sigma_v: -1.0 is not allowed"),
    ({"modes": ({"kind": "kf"}, {"kind": "kf", "motion": "ct"})}, "filter.modes[1].motion: 'ct' is nonlinear"),
    ({"modes": ({"kind": "kf"}, {"kind": "nope"})}, "filter.modes[1].kind: unknown filter 'nope'"),
    ({"modes": ({"kind": "kf"}, {"motion": "ct"})}, "filter.modes[1].kind: missing"),
    ({"modes": ({"kind": "kf"}, {"kind": "imm"})}, "filter.modes[1].kind: an IMM mode must be a single-model filter"),
    ({"modes": ({"kind": "kf"}, {"kind": "ekf", "bogus": 1})}, "filter.modes[1].bogus: unknown key"),
    ({"modes": ({"kind": "kf"}, {"kind": "ekf", "sigma_w": 2.0})}, "filter.modes[1]: measurement model"),
    ({"modes": ()}, "filter.modes: needs at least one mode table"),
    ({"transition": [[0.9, 0.05], [0.05, 0.95]]}, "filter.transition: row 0 sums to 0.95"),
    ({"transition": [[1.0]]}, "filter.transition: expected a 2 x 2 matrix"),
    ({"transition": [[1.2, -0.2], [0.0, 1.0]]}, "filter.transition: entries must be finite probabilities >= 0"),
    ({"transition": [[0.9, "a"], [0.1, 0.9]]}, "filter.transition[0][1]: expected a finite number, got 'a'"),
    ({"mu0": [0.5, 0.6]}, "filter.mu0: must be probabilities >= 0 summing to 1"),
    ({"mu0": [1.0]}, "filter.mu0: expected 2 mode probabilities"),
    ({"sigma_w": 0.0}, "filter.sigma_w: 0.0 is not allowed; must be > 0"),
])
def test_bad_tables_give_one_line_errors_with_dotted_keys(table, message):
    with pytest.raises(ParamError) as err:
        make_tracker("imm-pda-kf", filter=table)
    assert str(err.value).startswith(message), str(err.value)
    assert "\n" not in str(err.value)


def test_imm_filter_checks_its_markov_matrix_when_built_directly():
    kf = make_filter("kf")
    with pytest.raises(ValueError, match="transition: row 1 sums to 0.5"):
        IMMFilter((kf, kf), np.array([[0.5, 0.5], [0.25, 0.25]]), np.array([0.5, 0.5]))
    imm = IMMFilter((kf, kf), np.array([[1.0, 0.0], [0.0, 1.0]]), np.array([1.0, 0.0]))
    s = imm.predict(imm.initial_state(X0, P0), 0.1)  # mode 1 unreachable: mu stays [1, 0], no NaN
    np.testing.assert_array_equal(s.mu, [1.0, 0.0])
    assert np.isfinite(s.x).all() and imm.mode_names == ("cv0", "cv1")


# ---------------------------------------------------------------- batched paths against the per-track reference
def _modes(base: str) -> tuple[dict, ...]:
    return WRAPPERS["imm"](base)[1]["modes"]


IMM_BATCHED = {
    "kf": {"modes": _modes("kf")},  # KF-CV + EKF-CT
    "ekf": {"modes": _modes("ekf")},
    "svsf": {"modes": _modes("svsf")},  # SVSF-CV + GVBL-CT
    "gc-svsf": {"modes": _modes("gc-svsf")},
    "gvbl-svsf": {"modes": _modes("gvbl-svsf")},
    "gvbl-svsf-robust": {"modes": ({"kind": "gvbl-svsf", "psi_max": 0.5},
                                   {"kind": "gvbl-svsf", "motion": "ct", "psi_max": 0.5})},
    "three-modes": {"modes": ({"kind": "kf"}, {"kind": "ekf", "motion": "ct", "omega_std0": 0.3}, {"kind": "svsf"}),
                    "transition": [[0.9, 0.05, 0.05], [0.1, 0.8, 0.1], [0.2, 0.2, 0.6]], "mu0": [0.5, 0.3, 0.2]},
    "unreachable": {"modes": _modes("kf"), "transition": [[1.0, 0.0], [0.0, 1.0]], "mu0": [1.0, 0.0]},
    "svsf-reset": {"modes": tuple({**m, "memory_after_miss": "reset"} for m in _modes("svsf"))},  # issue 33
}


def _assert_same(a, b) -> None:
    fa, fb = state_fields(a), state_fields(b)
    assert set(fa) == set(fb), set(fa) ^ set(fb)
    assert type(a) is type(b) and all(type(x) is type(y) for x, y in zip(a.modes, b.modes))
    for k in fa:
        if fa[k] is None or fb[k] is None:
            assert fa[k] is None and fb[k] is None, k
            continue
        np.testing.assert_allclose(fa[k], fb[k], rtol=1e-12, atol=1e-12, err_msg=k)


def _batched_only() -> ExitStack:
    """A context in which the IMM's per-track predict / predicted_measurement / update fail: the batched forms
    under test must not fall back to them."""
    stack = ExitStack()
    for name in ("predict", "predicted_measurement", "update", "_state"):
        stack.enter_context(mock.patch.object(IMMFilter, name, side_effect=AssertionError(f"per-track {name}")))
    return stack


def _random_weights(rng, T: int, M: int) -> tuple[np.ndarray, np.ndarray]:
    """W (T, M), w0 (T,): per track a miss (w0 = 1, no weight), a hard association or PDA weights over a few."""
    W, w0 = np.zeros((T, M)), np.ones(T)
    for t, kind in enumerate(rng.integers(3, size=T)):
        if kind == 1:
            W[t, rng.integers(M)], w0[t] = 1.0, 0.0
        elif kind == 2:
            used = rng.random(M) < 0.5
            used[rng.integers(M)] = True
            p = rng.dirichlet(np.ones(int(used.sum()) + 1))
            W[t, used], w0[t] = p[1:], p[0]
    return W, w0


@pytest.mark.parametrize("T", [0, 1, 40])
@pytest.mark.parametrize("setting", list(IMM_BATCHED))
def test_the_batched_imm_equals_the_per_track_imm_to_1e_12(setting, T):
    """predict_many / predicted_measurements / update_many over T tracks and 8 scans (turning and straight
    CT modes, misses, hard and PDA weights, unused innovations) against the per-track predict /
    predicted_measurement / update (ModelFilter.update_many's loop), both from the same states each scan:
    x, P, e_post, mu, the info entries and every field of every mode state equal to 1e-12 (relative, or
    absolute near 0); a track without a measurement keeps its prediction (the same object), or with
    memory_after_miss = "reset" in its modes the prediction with every memory at 0."""
    from roadtrack.trackers.filters.base import ModelFilter

    imm = make_filter("imm", sigma_v=2.0, sigma_w=0.5, **IMM_BATCHED[setting])
    rng = np.random.default_rng(17)
    states = []
    for t in range(T):
        s = imm.initial_state(rng.normal(size=4) * [50, 5, 10, 2], np.diag([0.5, 0.5, 25.0, 25.0]))
        modes = tuple(replace(m, x=np.append(m.x[:4], rng.choice([0.0, 1e-7, 0.3]) * rng.normal()))
                      if m.x.size == 5 else m for m in s.modes)  # CT modes: straight, nearly and truly turning
        mu = rng.dirichlet(np.ones(len(modes))) if setting != "unreachable" else [[1.0, 0.0], [0.0, 1.0]][t % 2]
        states.append(replace(s, modes=modes, mu=np.asarray(mu, dtype=np.float64)))
    robust = 0
    for dt in (0.1, 0.1, 0.25, 0.0, 0.1, 0.1, 0.1, 0.1):
        with _batched_only():
            batch = imm.predict_many(states, dt)
        single = [imm.predict(s, dt) for s in states]
        assert len(batch) == T
        for a, b in zip(batch, single):
            _assert_same(a, b)
        with _batched_only():
            z_hat, S = imm.predicted_measurements(batch)
        assert z_hat.shape == (T, 2) and S.shape == (T, 2, 2)
        for t, s in enumerate(batch):
            z1, S1 = imm.predicted_measurement(s)
            np.testing.assert_allclose(z_hat[t], z1, rtol=1e-12, atol=1e-12)
            np.testing.assert_allclose(S[t], S1, rtol=1e-12, atol=1e-12)
        M = 5
        scale = rng.choice([0.5, 3.0], (T, 1, 1))
        nu = (np.linalg.cholesky(S)[:, None] @ rng.normal(size=(T, M, 2, 1)))[..., 0] * scale  # (T, M, 2)
        W, w0 = _random_weights(rng, T, M)
        nu[W == 0.0] = 1e6  # innovations the weights do not use must not matter
        with _batched_only():
            a = imm.update_many(batch, nu, W, w0)
        b = ModelFilter.update_many(imm, batch, nu, W, w0)
        for t, (u, v) in enumerate(zip(a, b)):
            _assert_same(u, v)
            if w0[t] == 1.0:  # a miss: the prediction itself, or with the modes' memories reset
                assert (u is batch[t]) == (setting != "svsf-reset")
                np.testing.assert_array_equal(u.e_post, 0.0 if setting == "svsf-reset" else batch[t].e_post)
            robust += sum(int(k.endswith("regime") and val == 1.0) for k, val in u.info.items())
        states = a
    if setting == "gvbl-svsf-robust" and T > 1:
        assert robust > 0  # the GVBL's robust (SVSF) gain was exercised


def test_the_batched_imm_raises_as_the_per_track_imm():
    """Bad input: the batched forms raise the per-track path's ValueError (same message) for non-finite used
    innovations or weights, rows not summing to 1, a bad dt; FilterError for a non-finite covariance.
    A non-finite innovation the weights do not use is ignored by both."""
    from roadtrack.trackers.filters.base import ModelFilter

    imm = make_filter("imm")
    preds = imm.predict_many([imm.initial_state(X0 + k, P0) for k in range(3)], 0.1)
    nu = np.full((3, 2, 2), 0.3)
    W, w0 = np.array([[0.5, 0.3], [1.0, 0.0], [0.0, 0.0]]), np.array([0.2, 0.0, 1.0])
    bad = []
    for what, value in [("nu", (1, 0, 1, np.nan)), ("nu", (0, 1, 0, np.inf)), ("W", (0, 1, np.nan)),
                        ("W", (0, 1, 0.2)), ("W", (1, 0, 0.0)), ("w0", (2, 0.5)), ("w0", (0, -0.2)),
                        ("w0", (1, np.nan)), ("W", (2, 0, np.inf))]:
        arrays = {"nu": nu.copy(), "W": W.copy(), "w0": w0.copy()}
        arrays[what][value[:-1]] = value[-1]
        bad.append(arrays)
    for arrays in bad:
        with pytest.raises(ValueError) as ref:
            ModelFilter.update_many(imm, preds, arrays["nu"], arrays["W"], arrays["w0"])
        with pytest.raises(ValueError) as got:
            imm.update_many(preds, arrays["nu"], arrays["W"], arrays["w0"])
        assert str(got.value) == str(ref.value)
    unused = nu.copy()
    unused[1, 1] = np.nan  # W[1, 1] = 0
    for u, v in zip(imm.update_many(preds, unused, W, w0), ModelFilter.update_many(imm, preds, unused, W, w0)):
        _assert_same(u, v)
    for dt in (-0.1, np.nan, np.inf):
        with pytest.raises(ValueError, match="finite dt >= 0"):
            imm.predict(preds[0], dt)
        with pytest.raises(ValueError, match="finite dt >= 0"):
            imm.predict_many(preds, dt)
    s = preds[0]
    broken = replace(s, modes=(replace(s.modes[0], P=np.full((4, 4), np.inf)), s.modes[1]))
    with pytest.raises(FilterError) as ref, np.errstate(invalid="ignore"):
        imm.predict(broken, 0.1)
    with pytest.raises(FilterError) as got, np.errstate(invalid="ignore"):
        imm.predict_many([preds[1], broken], 0.1)
    assert str(got.value) == str(ref.value)
