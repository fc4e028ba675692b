"""Symmetric measurement equations (SME): a joint EKF over N targets on a line, without association (paper 003).

N point targets move along one axis at constant velocity. The sensor reports their positions without labels, so
the filter is fed symmetric functions of the positions, which do not depend on the labels (paper 003 §II):

    sum of powers     y_m = sum_i z_i^m                          m = 1..N   (paper 003 §II eq. (3))
    sum of products   y_m = e_m(z) = sum_{|S|=m} prod_{i in S} z_i         (paper 003 §II, the second form)

with z_i = x_i + u_i, u_i ~ N(0, sigma^2) i.i.d. Writing y = g(x) + nu, the filter uses h(x) = E[y | x] = g(x) +
E[nu] (the sum of powers has a state-dependent noise mean, folded into h), the Jacobian dh/dx and the exact
covariance R(x) = Cov(nu | x), evaluated at the predicted positions.

How it sits beside trackers/tracker.py: `Tracker` keeps one filter per track and asks an associator which
measurement belongs to which track. The SME tracker has no association step: one joint state
x = [x_1..x_N, v_1..v_N] (positions first, paper 003 §II: H = [I_N 0_N]) holds every target, and one symmetric
measurement vector y (N,) per scan updates all of them at once. Its slots carry no identity; `label_permutation`
(scoring only, it reads truth) names them afterwards by the permutation of minimum squared error (paper 003 §IV).
The dynamics are the core's `ConstantVelocity(sigma_v=0, dims=N)`: N independent 1-D constant-velocity targets
have exactly the state, F = [[I, T I], [0, I]] and Q = 0 of one target moving in N axes (paper 003 eq. (1)).

Every array function broadcasts over leading axes, so one call filters a whole Monte Carlo batch:
positions (..., N), states x (..., 2N), covariances (..., 2N, 2N). Units: m, s.
"""

from __future__ import annotations

import functools
import itertools
import math
from dataclasses import dataclass, field

import numpy as np

from roadtrack.trackers.errors import FilterError
from roadtrack.trackers.models import ConstantVelocity

FORMS = ("powers", "products")


def _check_form(form: str) -> None:
    if form not in FORMS:
        raise ValueError(f"unknown symmetric form {form!r}; allowed: {', '.join(FORMS)}")


# ------------------------------------------------------------------------------- sum of powers
def _raw_moments(pos: np.ndarray, sigma: float, top: int) -> np.ndarray:
    """M_m(x) = E (x + u)^m for m = 0..top, u ~ N(0, sigma^2): (..., N, top + 1).

    reconstructed (paper 003 §III gives only the resulting matrices): by Stein's lemma E[u f(u)] = sigma^2 E f'(u),
    M_m = x M_{m-1} + (m - 1) sigma^2 M_{m-2}, M_0 = 1, M_1 = x."""
    pos = np.asarray(pos, dtype=np.float64)
    out = np.empty(pos.shape + (top + 1,))
    out[..., 0] = 1.0
    for m in range(1, top + 1):
        out[..., m] = pos * out[..., m - 1] + ((m - 1) * sigma ** 2 * out[..., m - 2] if m >= 2 else 0.0)
    return out


def _powers_h(pos: np.ndarray, sigma: float) -> np.ndarray:
    n = pos.shape[-1]
    M = _raw_moments(pos, sigma, n)
    return M[..., 1:].sum(axis=-2)  # paper 003 eq. (3) with E[nu] folded in: h_m = sum_i E (x_i + u_i)^m


def _powers_jacobian(pos: np.ndarray, sigma: float) -> np.ndarray:
    n = pos.shape[-1]
    M = _raw_moments(pos, sigma, n - 1)
    a = np.arange(1, n + 1, dtype=np.float64)
    return a[:, None] * np.swapaxes(M, -1, -2)  # reconstructed: d/dx E (x + u)^a = a M_{a-1}(x)


def _powers_covariance(pos: np.ndarray, sigma: float) -> np.ndarray:
    n = pos.shape[-1]
    M = _raw_moments(pos, sigma, 2 * n)
    a = np.arange(1, n + 1)
    second = M[..., a[:, None] + a[None, :]]  # (..., N, N, N): M_{a+b}(x_i)
    first = M[..., a][..., :, None] * M[..., a][..., None, :]
    return (second - first).sum(axis=-3)  # reconstructed: R_ab = sum_i [M_{a+b}(x_i) - M_a(x_i) M_b(x_i)]


# ----------------------------------------------------------------------------- sum of products
def _elementary(pos: np.ndarray) -> np.ndarray:
    """e_0..e_N of the last axis: (..., N + 1), by multiplying out prod_i (1 + x_i t)."""
    pos = np.asarray(pos, dtype=np.float64)
    n = pos.shape[-1]
    e = np.zeros(pos.shape[:-1] + (n + 1,))
    e[..., 0] = 1.0
    for i in range(n):
        e[..., 1:] = e[..., 1:] + pos[..., i, None] * e[..., :-1]
    return e


def _products_jacobian(pos: np.ndarray) -> np.ndarray:
    n = pos.shape[-1]
    J = np.empty(pos.shape[:-1] + (n, n))
    for i in range(n):
        others = np.delete(pos, i, axis=-1)
        J[..., :, i] = _elementary(others)  # reconstructed: d e_a / d x_i = e_{a-1}(x without x_i)
    return J


def _products_covariance(pos: np.ndarray, sigma: float) -> np.ndarray:
    """reconstructed (paper 003 §III gives N = 2, 3 only): E[e_a(z) e_b(z)] is the coefficient of s^a t^b in
    prod_i E[(1 + s z_i)(1 + t z_i)] = prod_i (1 + (s + t) x_i + s t (x_i^2 + sigma^2)); R_ab = that - e_a e_b."""
    n = pos.shape[-1]
    C = np.zeros(pos.shape[:-1] + (n + 1, n + 1))
    C[..., 0, 0] = 1.0
    for i in range(n):
        x, sq = pos[..., i, None, None], pos[..., i, None, None] ** 2 + sigma ** 2
        new = C.copy()
        new[..., 1:, :] += x * C[..., :-1, :]
        new[..., :, 1:] += x * C[..., :, :-1]
        new[..., 1:, 1:] += sq * C[..., :-1, :-1]
        C = new
    e = _elementary(pos)[..., 1:]
    R = C[..., 1:, 1:] - e[..., :, None] * e[..., None, :]
    return 0.5 * (R + np.swapaxes(R, -1, -2))  # exactly symmetric (the two recursions round differently)


# ------------------------------------------------------------------------------- public functions
def symmetric_g(pos: np.ndarray, form: str) -> np.ndarray:
    """Noise-free symmetric function g(x) of positions (..., N) -> (..., N) (paper 003 §II eq. (3)-(4))."""
    _check_form(form)
    pos = np.asarray(pos, dtype=np.float64)
    if form == "powers":
        return np.stack([(pos ** m).sum(axis=-1) for m in range(1, pos.shape[-1] + 1)], axis=-1)
    return _elementary(pos)[..., 1:]


def symmetric_h(pos: np.ndarray, form: str, sigma: float) -> np.ndarray:
    """h(x) = E[y | x] (..., N): g(x) plus the noise mean, which is non-zero for the sum of powers
    (paper 003 §II: E[nu] = [0, 2 sigma^2] for N = 2; reconstructed for N = 3: [0, 3 sigma^2, 3 sigma^2 S_1])."""
    _check_form(form)
    pos = np.asarray(pos, dtype=np.float64)
    return _powers_h(pos, sigma) if form == "powers" else symmetric_g(pos, form)


def symmetric_noise_mean(pos: np.ndarray, form: str, sigma: float) -> np.ndarray:
    """E[nu] = h(x) - g(x) (..., N)."""
    return symmetric_h(pos, form, sigma) - symmetric_g(pos, form)


def symmetric_jacobian(pos: np.ndarray, form: str, sigma: float) -> np.ndarray:
    """J = dh/dx (..., N, N), rows m = 1..N, columns the positions; singular where two positions coincide."""
    _check_form(form)
    pos = np.asarray(pos, dtype=np.float64)
    return _powers_jacobian(pos, sigma) if form == "powers" else _products_jacobian(pos)


def symmetric_noise_covariance(pos: np.ndarray, form: str, sigma: float) -> np.ndarray:
    """R(x) = Cov(nu | x) (..., N, N), exact for any N (paper 003 §III gives N = 2, 3; general form reconstructed)."""
    _check_form(form)
    pos = np.asarray(pos, dtype=np.float64)
    return _powers_covariance(pos, sigma) if form == "powers" else _products_covariance(pos, sigma)


@dataclass(frozen=True)
class SymmetricMeasurement:
    """y = h(x) + nu on the joint state x = [x_1..x_N, v_1..v_N] (..., 2N). form: "powers" or "products";
    n_targets: N; sigma [m]: raw position noise std (paper 003 §IV: sigma^2 = 25)."""

    form: str
    n_targets: int
    sigma: float = 5.0
    linear: bool = field(default=False, init=False)

    def __post_init__(self) -> None:
        _check_form(self.form)
        if isinstance(self.n_targets, bool) or not isinstance(self.n_targets, int) or self.n_targets < 1:
            raise ValueError(f"SymmetricMeasurement.n_targets must be an int >= 1, got {self.n_targets!r}")
        if not (isinstance(self.sigma, (int, float)) and math.isfinite(self.sigma) and self.sigma > 0):
            raise ValueError(f"SymmetricMeasurement.sigma must be a finite number > 0, got {self.sigma!r}")

    @property
    def ndim(self) -> int:
        return self.n_targets

    def h(self, x: np.ndarray) -> np.ndarray:
        return symmetric_h(np.asarray(x)[..., : self.n_targets], self.form, self.sigma)

    def jacobian(self, x: np.ndarray) -> np.ndarray:
        """H = [J 0_N] (..., N, 2N): the velocities do not enter h."""
        J = symmetric_jacobian(np.asarray(x)[..., : self.n_targets], self.form, self.sigma)
        return np.concatenate([J, np.zeros_like(J)], axis=-1)

    def noise(self, x: np.ndarray) -> np.ndarray:
        return symmetric_noise_covariance(np.asarray(x)[..., : self.n_targets], self.form, self.sigma)


# --------------------------------------------------------------------------------------- tracker
@dataclass(frozen=True, eq=False)
class SMEState:
    """Joint estimate: x (..., 2N) = [x_1..x_N, v_1..v_N] [m, m/s]; P (..., 2N, 2N). Leading axes: a batch."""

    x: np.ndarray
    P: np.ndarray


@dataclass(frozen=True)
class SMETracker:
    """Joint multi-target EKF on a symmetric measurement; no association, no track management.

    Stateless: `step(state, y, dt) -> (state, estimates)`; `predict` and `update` are its two halves. The
    slots of the estimate are unlabelled; name them with `label_permutation` when truth is known."""

    measurement: SymmetricMeasurement

    @property
    def motion(self) -> ConstantVelocity:
        # paper 003 eq. (1) with Q = 0 (paper 003 §II, constant velocity): the core's NCV in N axes
        return ConstantVelocity(sigma_v=0.0, dims=self.measurement.n_targets)

    def initial_state(self, x0: np.ndarray, P0: np.ndarray) -> SMEState:
        n = 2 * self.measurement.n_targets
        x0, P0 = np.array(x0, dtype=np.float64), np.array(P0, dtype=np.float64)
        if x0.shape[-1:] != (n,) or P0.shape[-2:] != (n, n):
            raise ValueError(f"initial_state needs x0 (..., {n}) and P0 (..., {n}, {n}), got {x0.shape}, {P0.shape}")
        return SMEState(x=x0, P=P0)

    def predict(self, s: SMEState, dt: float) -> SMEState:
        """x = F x, P = F P F^T + Q (Q = 0) (paper 003 eq. (1))."""
        F = self.motion.transition(dt)
        P = F @ s.P @ F.T + self.motion.process_noise(dt)  # paper 003 eq. (1): Q = 0
        return SMEState(x=s.x @ F.T, P=0.5 * (P + np.swapaxes(P, -1, -2)))

    def update(self, s_pred: SMEState, y: np.ndarray) -> SMEState:
        """EKF update with h, H and R(x) at the prediction; Joseph-form covariance. y (..., N)."""
        meas = self.measurement
        y = np.asarray(y, dtype=np.float64)
        H, R = meas.jacobian(s_pred.x), meas.noise(s_pred.x)  # R at the predicted positions [D]
        HP = H @ s_pred.P
        S = HP @ np.swapaxes(H, -1, -2) + R
        d = 1.0 / np.sqrt(np.diagonal(S, axis1=-2, axis2=-1))  # scale rows: y_m spans m-th powers of positions
        Sn = d[..., :, None] * S * d[..., None, :]
        K = np.swapaxes(np.linalg.solve(Sn, d[..., :, None] * HP), -1, -2) * d[..., None, :]  # K = P H^T S^-1
        nu = y - meas.h(s_pred.x)
        x = s_pred.x + (K @ nu[..., None])[..., 0]
        I_KH = np.eye(s_pred.x.shape[-1]) - K @ H
        P = I_KH @ s_pred.P @ np.swapaxes(I_KH, -1, -2) + K @ R @ np.swapaxes(K, -1, -2)  # Joseph form
        P = 0.5 * (P + np.swapaxes(P, -1, -2))
        if not (np.isfinite(x).all() and np.isfinite(P).all()):
            raise FilterError("SME update gave a non-finite state or covariance")
        return SMEState(x=x, P=P)

    def step(self, s: SMEState, y: np.ndarray, dt: float) -> tuple[SMEState, np.ndarray]:
        """One scan: predict by dt [s], update with y (..., N). Returns the state and the unlabelled estimates
        (..., N, 2): slot i is [position, velocity]."""
        s = self.update(self.predict(s, dt), y)
        return s, self.estimates(s)

    def estimates(self, s: SMEState) -> np.ndarray:
        n = self.measurement.n_targets
        return np.stack([s.x[..., :n], s.x[..., n:]], axis=-1)


# ------------------------------------------------------------------------------------- labelling
@functools.lru_cache(maxsize=8)
def permutations(n: int) -> np.ndarray:
    """All permutations of range(n): (n!, n) int64, identity first (read-only)."""
    p = np.array(list(itertools.permutations(range(n))), dtype=np.int64)
    p.setflags(write=False)
    return p


def label_permutation(x_est: np.ndarray, x_true: np.ndarray) -> np.ndarray:
    """perm (..., N) int64 such that slot perm[i] of x_est is target i of x_true, minimising
    sum_i (x_est[perm[i]] - x_i)^2 + (v_est[perm[i]] - v_i)^2 (paper 003 §IV; joint position-velocity error
    and per-step labelling are [D]). x_est, x_true (..., 2N); for scoring only (reads truth)."""
    x_est, x_true = np.asarray(x_est, dtype=np.float64), np.asarray(x_true, dtype=np.float64)
    n = x_est.shape[-1] // 2
    perms = permutations(n)
    est = x_est.reshape(x_est.shape[:-1] + (2, n))[..., perms]  # (..., 2, n!, N)
    tru = x_true.reshape(x_true.shape[:-1] + (2, n))[..., None, :]
    cost = ((est - tru) ** 2).sum(axis=(-3, -1))  # (..., n!)
    return perms[np.argmin(cost, axis=-1)]


def relabel(x_est: np.ndarray, perm: np.ndarray) -> np.ndarray:
    """x_est (..., 2N) with slot perm[i] moved to place i (positions and velocities together)."""
    n = x_est.shape[-1] // 2
    idx = np.concatenate([perm, perm + n], axis=-1)
    return np.take_along_axis(np.asarray(x_est), idx, axis=-1)
