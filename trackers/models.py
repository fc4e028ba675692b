"""Motion and measurement models as data (thesis §1.1-1.3).

A motion model gives its state size `ndim`, which entries are position and velocity (`position`,
`velocity`, index tuples, positions first), the transition `f(x, dt)`, its Jacobian `jacobian(x, dt)`
(n, n) and the process noise `process_noise(dt)` (n, n). `embed(x, P)` lifts a kinematic Gaussian
[p; v] (2d,) into the model's state (e.g. a turn rate appended with its prior variance), `embed_many`
the same for T of them at once ((T, 2d), (T, 2d, 2d)). A nonlinear model may offer `f_many(X, dt)` and
`jacobian_many(X, dt)` for T states X (T, n) at once (the CT model does); its process noise must then not depend on x.

A measurement model gives `ndim` (m), `h(x, motion)`, `jacobian(x, motion)` (m, n), the noise `R` (m, m),
`residual(z, z_hat)` (angle wrapping for bearings) and `position_of(z)`: the position and its
covariance that one measurement implies (used by initiators). Models are frozen dataclasses; filters
are generic over them. Units: m, s, rad.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import numpy as np


def _check_finite(owner: str, **values: float) -> None:
    for name, v in values.items():
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise ValueError(f"{owner}.{name} must be a finite number, got {v!r}")


# --------------------------------------------------------------------------------------------- motion
@functools.lru_cache(maxsize=64)
def _cv_transition(dims: int, dt: float) -> np.ndarray:
    A = np.eye(2 * dims)  # (1.36)-(1.38) NCV: A = [[I, dt I], [0, I]]
    A[range(dims), range(dims, 2 * dims)] = dt
    A.setflags(write=False)
    return A


@functools.lru_cache(maxsize=64)
def _cv_noise(dims: int, dt: float, sigma_v: float) -> np.ndarray:
    G = np.vstack([0.5 * dt * dt * np.eye(dims), dt * np.eye(dims)])  # (1.36)-(1.38) NCV gain G
    Q = (sigma_v ** 2) * (G @ G.T)  # thesis §1.1 [R]: Q = G Qv G^T (dimensionally consistent (1.38))
    Q.setflags(write=False)
    return Q


@dataclass(frozen=True)
class ConstantVelocity:
    """Near-constant velocity (white acceleration) in `dims` spatial axes: state [p_1..p_d, v_1..v_d].

    sigma_v [m/s^2]: white-acceleration std per axis. dims = 2 for the road plane, 1 for the papers'
    1-D targets (seed 000, 003)."""

    sigma_v: float
    dims: int = 2
    linear: bool = field(default=True, init=False)

    def __post_init__(self) -> None:
        _check_finite("ConstantVelocity", sigma_v=self.sigma_v)
        if self.sigma_v < 0:
            raise ValueError(f"ConstantVelocity.sigma_v must be >= 0, got {self.sigma_v}")
        if self.dims not in (1, 2, 3):
            raise ValueError(f"ConstantVelocity.dims must be 1, 2 or 3, got {self.dims!r}")

    @property
    def ndim(self) -> int:
        return 2 * self.dims

    @property
    def position(self) -> tuple[int, ...]:
        return tuple(range(self.dims))

    @property
    def velocity(self) -> tuple[int, ...]:
        return tuple(range(self.dims, 2 * self.dims))

    def transition(self, dt: float) -> np.ndarray:
        """A (n, n) = [[I, dt I], [0, I]] (read-only, cached per dt)."""
        return _cv_transition(self.dims, float(dt))

    def f(self, x: np.ndarray, dt: float) -> np.ndarray:
        return self.transition(dt) @ x

    def jacobian(self, x: np.ndarray, dt: float) -> np.ndarray:
        return self.transition(dt)

    def noise_gain(self, dt: float) -> np.ndarray:
        """G (n, d): white acceleration enters as [dt^2/2 I; dt I]."""
        d = self.dims
        return np.vstack([0.5 * dt * dt * np.eye(d), dt * np.eye(d)])  # (1.36)-(1.38) NCV gain G

    def process_noise(self, dt: float, x: np.ndarray | None = None) -> np.ndarray:
        """Q = G Qv G^T (n, n), Qv = sigma_v^2 I (read-only, cached per dt)."""
        return _cv_noise(self.dims, float(dt), float(self.sigma_v))

    def embed(self, x: np.ndarray, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Kinematic [p; v] (2d,) and (2d, 2d) -> model state: the identity for NCV."""
        return np.asarray(x, dtype=np.float64), np.asarray(P, dtype=np.float64)

    def embed_many(self, X: np.ndarray, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """`embed` of T kinematic Gaussians at once: X (T, 2d), P (T, 2d, 2d) -> the same (the identity)."""
        return np.asarray(X, dtype=np.float64), np.asarray(P, dtype=np.float64)


SERIES_BELOW = 0.5
"""|omega dt| below which `CoordinatedTurn` evaluates its turn terms by Taylor series. The closed forms lose about
3 eps / (omega dt)^2 of relative accuracy to cancellation (1e-15 at 0.5, 3e-8 at 1e-4); SERIES_TERMS terms of
the series are exact to rounding below it (the first omitted term is under 1e-19 relative at 0.5)."""
SERIES_TERMS = 8


def taylor(coefficients: tuple[float, ...], t2: float | np.ndarray) -> float | np.ndarray:
    """sum_k coefficients[k] t2^k by Horner's rule (of each entry of an array t2, with the same float operations)."""
    out = 0.0
    for c in reversed(coefficients):
        out = out * t2 + c
    return out


SINC = tuple((-1) ** k / math.factorial(2 * k + 1) for k in range(SERIES_TERMS))
"""sin(t) / t = sum_k SINC[k] t^2k."""
VERSINE = tuple((-1) ** k / math.factorial(2 * k + 2) for k in range(SERIES_TERMS))
"""(1 - cos t) / t^2 = sum_k VERSINE[k] t^2k."""
DSINC = tuple((-1) ** (k + 1) * (2 * k + 2) / math.factorial(2 * k + 3) for k in range(SERIES_TERMS))
"""(t cos t - sin t) / t^3 = sum_k DSINC[k] t^2k."""
DVERSINE = tuple((-1) ** k * (2 * k + 1) / math.factorial(2 * k + 2) for k in range(SERIES_TERMS))
"""(t sin t - (1 - cos t)) / t^2 = sum_k DVERSINE[k] t^2k."""


@dataclass(frozen=True)
class CoordinatedTurn:
    """Near-constant-speed coordinated turn, state [px, py, vx, vy, omega] (thesis §1.3, (1.39)-(1.40);
    the printed matrices are lost, so the standard form of Bar-Shalom, Li & Kirubarajan §11.7 is used).

    sigma_v [m/s^2] white acceleration on each axis; sigma_omega [rad/s^2] on the turn rate;
    omega_std0 [rad/s]: prior std of the turn rate of a new track (embed)."""

    sigma_v: float
    sigma_omega: float = 0.02
    omega_std0: float = 0.1
    linear: bool = field(default=False, init=False)
    dims: int = field(default=2, init=False)

    def __post_init__(self) -> None:
        _check_finite("CoordinatedTurn", sigma_v=self.sigma_v, sigma_omega=self.sigma_omega,
                      omega_std0=self.omega_std0)
        if self.sigma_v < 0 or self.sigma_omega < 0 or self.omega_std0 <= 0:
            raise ValueError("CoordinatedTurn needs sigma_v, sigma_omega >= 0 and omega_std0 > 0")

    ndim = 5
    position = (0, 1)
    velocity = (2, 3)

    @staticmethod
    def _terms(w: float, dt: float) -> tuple[float, float]:
        """(sin(w dt) / w, (1 - cos(w dt)) / w): the closed form for |w dt| >= SERIES_BELOW, else the Taylor
        series in w dt (the closed 1 - cos loses digits to cancellation; the series is exact at w = 0)."""
        t = w * dt
        if abs(t) < SERIES_BELOW:
            t2 = t * t
            return dt * taylor(SINC, t2), dt * t * taylor(VERSINE, t2)  # (1.39)-(1.40) [R], series form
        return math.sin(t) / w, (1.0 - math.cos(t)) / w

    def transition(self, dt: float, omega: float) -> np.ndarray:
        """A_CT(omega) (5, 5)."""
        s, c1 = self._terms(omega, dt)
        co, si = math.cos(omega * dt), math.sin(omega * dt)
        return np.array([[1, 0, s, -c1, 0], [0, 1, c1, s, 0], [0, 0, co, -si, 0], [0, 0, si, co, 0],
                         [0, 0, 0, 0, 1]], dtype=np.float64)  # thesis §1.3 [R]: A_CT(omega)

    def f(self, x: np.ndarray, dt: float) -> np.ndarray:
        return self.transition(dt, float(x[4])) @ x  # §1.3 f(x) = A_CT(omega) x

    def jacobian(self, x: np.ndarray, dt: float) -> np.ndarray:
        """F_J = df/dx at x: A_CT(omega) with the last column replaced by df/domega (thesis (1.39)-(1.40) [R]).

        df/domega holds a = (w dt cos - sin) / w^2 and b = (w dt sin - (1 - cos)) / w^2, whose closed forms
        cancel (a ~ -dt^3 w / 3 from terms of size dt / w); below |w dt| = SERIES_BELOW their Taylor series
        are used, accurate to ~1e-16 relative (tests/test_coordinated_turn.py checks every entry against a
        60-digit evaluation for |omega| in [0, 1])."""
        w, vx, vy = float(x[4]), float(x[2]), float(x[3])
        F = self.transition(dt, w)
        sw, cw, a, b = self._turn_derivative(w, dt)
        F[:, 4] = [vx * a - vy * b, vx * b + vy * a, -dt * (sw * vx + cw * vy), dt * (cw * vx - sw * vy), 1.0]
        return F

    @staticmethod
    def _turn_derivative(w: float, dt: float) -> tuple[float, float, float, float]:
        """sin(w dt), cos(w dt) (libm) and the entries a, b of d(A x)/domega [s^2] of turn rate w [rad/s] over dt [s]
        (the series form below SERIES_BELOW, shared by `jacobian` and the batched `_turns`)."""
        t = w * dt
        sw, cw = math.sin(t), math.cos(t)
        if abs(t) < SERIES_BELOW:
            t2 = t * t
            return sw, cw, dt * dt * t * taylor(DSINC, t2), dt * dt * taylor(DVERSINE, t2)  # series form of a, b
        return sw, cw, (w * dt * cw - sw) / w ** 2, (w * dt * sw - (1.0 - cw)) / w ** 2

    # ---- batched forms: X (T, 5) -> (T, 5) and (T, 5, 5), from the per-track scalars (libm sin / cos, the series
    # switch) computed track by track, then placed and combined entry by entry with the same float operations, so
    # A and F are bit-identical to the per-track ones (numpy's vectorised sin / cos need not round as libm's do,
    # and an ulp in cos(w dt) is amplified near the switch).
    def transition_many(self, dt: float, omega: np.ndarray) -> np.ndarray:
        """A_CT(omega_t) of T turn rates omega (T,): (T, 5, 5)."""
        return self._assemble(self._turns(dt, omega)[:, :4])

    def _turns(self, dt: float, omega: np.ndarray) -> np.ndarray:
        """Per turn rate the scalars of `transition` and `jacobian`, (T, 6): sin(w dt) / w, (1 - cos(w dt)) / w,
        cos(w dt), sin(w dt), and df/domega's a, b, as the per-track code computes them: sin and cos by libm track by
        track, the series (|w dt| < SERIES_BELOW) as the same float operations on arrays (Horner's rule, products
        left to right), the closed forms (large turn rates, rare) by the per-track code."""
        w = np.asarray(omega, dtype=np.float64).reshape(-1)
        t = w * dt
        ts = t.tolist()
        t2 = t * t
        out = np.empty((w.size, 6))
        out[:, 2] = [math.cos(v) for v in ts]  # libm; ValueError for an infinite w dt, as per track
        out[:, 3] = [math.sin(v) for v in ts]
        out[:, 0] = dt * taylor(SINC, t2)  # (1.39)-(1.40) [R], series form (`_terms`)
        out[:, 1] = dt * t * taylor(VERSINE, t2)
        out[:, 4] = dt * dt * t * taylor(DSINC, t2)  # series form of a, b (`_turn_derivative`)
        out[:, 5] = dt * dt * taylor(DVERSINE, t2)
        for k in np.flatnonzero(~(np.abs(t) < SERIES_BELOW)).tolist():  # the closed forms
            wk = float(w[k])
            s, c1 = self._terms(wk, dt)
            sw, cw, a, b = self._turn_derivative(wk, dt)
            out[k] = (s, c1, cw, sw, a, b)
        return out

    @staticmethod
    def _assemble(turns: np.ndarray) -> np.ndarray:
        """A_CT (T, 5, 5) from the scalars (T, >= 4) of `_turns`, entry by entry as `transition` places them."""
        s, c1, co, si = turns[:, 0], turns[:, 1], turns[:, 2], turns[:, 3]
        A = np.zeros((len(turns), 5, 5))
        A[:, 0, 0] = A[:, 1, 1] = A[:, 4, 4] = 1.0
        A[:, 0, 2], A[:, 0, 3], A[:, 1, 2], A[:, 1, 3] = s, -c1, c1, s  # thesis §1.3 [R]: A_CT(omega)
        A[:, 2, 2], A[:, 2, 3], A[:, 3, 2], A[:, 3, 3] = co, -si, si, co
        return A

    def f_many(self, X: np.ndarray, dt: float) -> np.ndarray:
        """`f` of T states X (T, 5): (T, 5)."""
        return np.einsum("tij,tj->ti", self.transition_many(dt, X[:, 4]), X)  # §1.3 f(x) = A_CT(omega) x

    def jacobian_many(self, X: np.ndarray, dt: float) -> np.ndarray:
        """`jacobian` of T states X (T, 5): (T, 5, 5)."""
        X = np.asarray(X, dtype=np.float64).reshape(-1, 5)
        turns = self._turns(dt, X[:, 4])
        return self._jacobian_from(self._assemble(turns), X, turns, dt)

    def f_and_jacobian_many(self, X: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """(`f_many`, `jacobian_many`) of T states X (T, 5) from one pass of the per-track turn terms (`_turns`)."""
        X = np.asarray(X, dtype=np.float64).reshape(-1, 5)
        turns = self._turns(dt, X[:, 4])
        A = self._assemble(turns)
        fx = np.einsum("tij,tj->ti", A, X)  # §1.3 f(x) = A_CT(omega) x
        return fx, self._jacobian_from(A, X, turns, dt)

    @staticmethod
    def _jacobian_from(F: np.ndarray, X: np.ndarray, turns: np.ndarray, dt: float) -> np.ndarray:
        """A_CT (T, 5, 5) made the Jacobian in place: its last column df/domega from X (T, 5) and `_turns`."""
        vx, vy, cw, sw, a, b = X[:, 2], X[:, 3], turns[:, 2], turns[:, 3], turns[:, 4], turns[:, 5]
        F[:, 0, 4], F[:, 1, 4] = vx * a - vy * b, vx * b + vy * a  # (1.39)-(1.40) [R]: df/domega
        F[:, 2, 4], F[:, 3, 4] = -dt * (sw * vx + cw * vy), dt * (cw * vx - sw * vy)
        return F

    def process_noise(self, dt: float, x: np.ndarray | None = None) -> np.ndarray:
        """Q = B diag(sigma_v^2, sigma_v^2, sigma_omega^2) B^T (5, 5) (§1.3 [R/D]); the same for every x."""
        B = np.zeros((5, 3))
        B[0, 0] = B[1, 1] = 0.5 * dt * dt
        B[2, 0] = B[3, 1] = B[4, 2] = dt
        return B @ np.diag([self.sigma_v ** 2, self.sigma_v ** 2, self.sigma_omega ** 2]) @ B.T

    def embed(self, x: np.ndarray, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Kinematic [px, py, vx, vy] -> [.., omega = 0] with variance omega_std0^2 (thesis §5 IMM [D])."""
        x5 = np.zeros(5)
        x5[:4] = x
        P5 = np.zeros((5, 5))
        P5[:4, :4] = P
        P5[4, 4] = self.omega_std0 ** 2
        return x5, P5

    def embed_many(self, X: np.ndarray, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """`embed` of T kinematic Gaussians at once: X (T, 4), P (T, 4, 4) -> (T, 5), (T, 5, 5)."""
        X5 = np.zeros((len(X), 5))
        X5[:, :4] = X
        P5 = np.zeros((len(X), 5, 5))
        P5[:, :4, :4] = P
        P5[:, 4, 4] = self.omega_std0 ** 2  # thesis §5 IMM [D]: omega = 0 with variance omega_std0^2
        return X5, P5


MOTION_MODELS = {"cv": ConstantVelocity, "ct": CoordinatedTurn}


# ----------------------------------------------------------------------------------------- measurement
@functools.lru_cache(maxsize=64)
def _selection(m: int, n: int, position: tuple[int, ...]) -> np.ndarray:
    H = np.zeros((m, n))
    H[range(m), position] = 1.0
    H.setflags(write=False)
    return H


@functools.lru_cache(maxsize=64)
def _scaled_eye(m: int, variance: float) -> np.ndarray:
    R = variance * np.eye(m)
    R.setflags(write=False)
    return R


@dataclass(frozen=True)
class PositionMeasurement:
    """z = H x + w: the motion model's position entries, R = sigma_w^2 I (thesis (4.77)-(4.79)). sigma_w [m].
    per_detection: a detection's own covariance R_j, when the caller gives one (`Tracker.step(R=...)`), replaces R
    in the gate, the likelihood and the update; R = sigma_w^2 I is the fallback."""

    sigma_w: float
    dims: int = 2
    per_detection: bool = False
    linear: bool = field(default=True, init=False)

    def __post_init__(self) -> None:
        _check_finite("PositionMeasurement", sigma_w=self.sigma_w)
        if self.sigma_w <= 0:
            raise ValueError(f"PositionMeasurement.sigma_w must be > 0, got {self.sigma_w}")
        if self.dims not in (1, 2, 3):
            raise ValueError(f"PositionMeasurement.dims must be 1, 2 or 3, got {self.dims!r}")

    @property
    def ndim(self) -> int:
        return self.dims

    @property
    def R(self) -> np.ndarray:
        return _scaled_eye(self.dims, float(self.sigma_w) ** 2)  # (4.77)-(4.79) R = sigma_w^2 I

    def matrix(self, motion) -> np.ndarray:
        """H (m, n): ones at the motion model's position entries (positions first: H = [I 0], §1.2); read-only."""
        return _selection(self.dims, motion.ndim, tuple(motion.position[: self.dims]))

    def h(self, x: np.ndarray, motion) -> np.ndarray:
        return x[list(motion.position[: self.dims])]

    def jacobian(self, x: np.ndarray, motion) -> np.ndarray:
        return self.matrix(motion)

    def residual(self, z: np.ndarray, z_hat: np.ndarray) -> np.ndarray:
        """z - z_hat, broadcast over leading axes."""
        return z - z_hat

    def position_of(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(position (d,), covariance R) implied by one measurement."""
        return np.asarray(z, dtype=np.float64), self.R


def polar_position(origin, r: float, b: float, R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(position (2,), covariance (2, 2)) of range r [m] and bearing b [rad] from origin (2,), R the (range,
    bearing) covariance (2, 2), by the first-order Jacobian."""
    p = np.array([origin[0] + r * math.cos(b), origin[1] + r * math.sin(b)])
    J = np.array([[math.cos(b), -r * math.sin(b)], [math.sin(b), r * math.cos(b)]])
    return p, J @ R @ J.T


@dataclass(frozen=True)
class RangeBearing:
    """z = [range, bearing] of the position seen from `origin` (a nonlinear model for the EKF).
    sigma_r [m], sigma_b [rad]; the bearing residual is wrapped to (-pi, pi]."""

    sigma_r: float
    sigma_b: float
    origin: tuple[float, float] = (0.0, 0.0)
    linear: bool = field(default=False, init=False)
    ndim = 2
    dims = 2

    def __post_init__(self) -> None:
        _check_finite("RangeBearing", sigma_r=self.sigma_r, sigma_b=self.sigma_b)
        if self.sigma_r <= 0 or self.sigma_b <= 0:
            raise ValueError("RangeBearing needs sigma_r > 0 and sigma_b > 0")

    @property
    def R(self) -> np.ndarray:
        return np.diag([self.sigma_r ** 2, self.sigma_b ** 2])

    def h(self, x: np.ndarray, motion) -> np.ndarray:
        dx, dy = x[motion.position[0]] - self.origin[0], x[motion.position[1]] - self.origin[1]
        return np.array([math.hypot(dx, dy), math.atan2(dy, dx)])

    def jacobian(self, x: np.ndarray, motion) -> np.ndarray:
        dx, dy = x[motion.position[0]] - self.origin[0], x[motion.position[1]] - self.origin[1]
        r2 = max(dx * dx + dy * dy, 1e-12)
        r = math.sqrt(r2)
        H = np.zeros((2, motion.ndim))
        H[0, motion.position[0]], H[0, motion.position[1]] = dx / r, dy / r  # d range / d position
        H[1, motion.position[0]], H[1, motion.position[1]] = -dy / r2, dx / r2  # d bearing / d position
        return H

    def hessians(self, x: np.ndarray, motion) -> np.ndarray:
        """Second derivatives (m, n, n) of h at x (second-order EKF, seed 000)."""
        i, j = motion.position[0], motion.position[1]
        dx, dy = x[i] - self.origin[0], x[j] - self.origin[1]
        r2 = max(dx * dx + dy * dy, 1e-12)
        r3 = r2 ** 1.5
        Hs = np.zeros((2, motion.ndim, motion.ndim))
        Hs[0, i, i], Hs[0, j, j], Hs[0, i, j] = dy * dy / r3, dx * dx / r3, -dx * dy / r3
        Hs[0, j, i] = Hs[0, i, j]
        Hs[1, i, i], Hs[1, j, j], Hs[1, i, j] = 2 * dx * dy / r2 ** 2, -2 * dx * dy / r2 ** 2, (dy * dy - dx * dx) / r2 ** 2
        Hs[1, j, i] = Hs[1, i, j]
        return Hs

    def residual(self, z: np.ndarray, z_hat: np.ndarray) -> np.ndarray:
        nu = np.array(z - z_hat, dtype=np.float64)
        nu[..., 1] = (nu[..., 1] + math.pi) % (2.0 * math.pi) - math.pi
        return nu

    def position_of(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return polar_position(self.origin, float(z[0]), float(z[1]), self.R)


@dataclass(frozen=True)
class RangeBearingRate:
    """z = [range, azimuth, range-rate] of a target seen by a radar at ``pose`` = (x, y, heading) moving with
    ``velocity`` = (vx, vy) (a nonlinear model for the EKF; the sensor's pose rides with the model, so each scan's
    detections carry the model of the scan they were taken in). With d = p - s and u = v - v_s (target minus
    sensor position and velocity): range |d|, azimuth atan2(d_y, d_x) - heading (wrapped to (-pi, pi]), range-rate
    d.u / |d|. sigma_r [m], sigma_az [rad], sigma_rr [m/s]."""

    sigma_r: float
    sigma_az: float
    sigma_rr: float
    pose: tuple[float, float, float] = (0.0, 0.0, 0.0)
    velocity: tuple[float, float] = (0.0, 0.0)
    per_detection: bool = False
    linear: bool = field(default=False, init=False)
    ndim = 3
    dims = 2

    def __post_init__(self) -> None:
        _check_finite("RangeBearingRate", sigma_r=self.sigma_r, sigma_az=self.sigma_az, sigma_rr=self.sigma_rr,
                      x=self.pose[0], y=self.pose[1], heading=self.pose[2], vx=self.velocity[0], vy=self.velocity[1])
        if self.sigma_r <= 0 or self.sigma_az <= 0 or self.sigma_rr <= 0:
            raise ValueError("RangeBearingRate needs sigma_r, sigma_az and sigma_rr > 0")

    @property
    def R(self) -> np.ndarray:
        return np.diag([self.sigma_r ** 2, self.sigma_az ** 2, self.sigma_rr ** 2])

    def _relative(self, x: np.ndarray, motion) -> tuple[float, float, float, float]:
        (i, j), (k, l) = motion.position[:2], motion.velocity[:2]
        return (x[i] - self.pose[0], x[j] - self.pose[1], x[k] - self.velocity[0], x[l] - self.velocity[1])

    def h(self, x: np.ndarray, motion) -> np.ndarray:
        dx, dy, ux, uy = self._relative(x, motion)
        r = max(math.hypot(dx, dy), 1e-6)
        az = (math.atan2(dy, dx) - self.pose[2] + math.pi) % (2.0 * math.pi) - math.pi
        return np.array([r, az, (dx * ux + dy * uy) / r])

    def jacobian(self, x: np.ndarray, motion) -> np.ndarray:
        """H (3, n): d[range, azimuth, range-rate] / d state at x."""
        dx, dy, ux, uy = self._relative(x, motion)
        r2 = max(dx * dx + dy * dy, 1e-12)
        r = math.sqrt(r2)
        rr = (dx * ux + dy * uy) / r
        (i, j), (k, l) = motion.position[:2], motion.velocity[:2]
        H = np.zeros((3, motion.ndim))
        H[0, i], H[0, j] = dx / r, dy / r
        H[1, i], H[1, j] = -dy / r2, dx / r2
        H[2, i], H[2, j] = (ux - rr * dx / r) / r, (uy - rr * dy / r) / r  # d (d.u / |d|) / d p
        H[2, k], H[2, l] = dx / r, dy / r
        return H

    def residual(self, z: np.ndarray, z_hat: np.ndarray) -> np.ndarray:
        """z - z_hat with the azimuth wrapped to (-pi, pi], as RangeBearing's bearing."""
        return RangeBearing.residual(self, z, z_hat)

    def position_of(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(position (2,), its covariance (2, 2)) of one detection [range, azimuth, range-rate] (range-rate unused)."""
        return polar_position(self.pose[:2], float(z[0]), float(z[1]) + self.pose[2], self.R[:2, :2])


MEASUREMENT_MODELS = {"position": PositionMeasurement, "range_bearing": RangeBearing,
                      "range_bearing_rate": RangeBearingRate}


# -------------------------------------------------------------------------- plain functions (2-D NCV)
def cv_transition(dt: float) -> np.ndarray:
    """2-D NCV transition matrix A (4, 4) for a step of `dt` seconds."""
    return ConstantVelocity(0.0).transition(dt).copy()


def cv_noise_gain(dt: float) -> np.ndarray:
    """2-D NCV process-noise gain G (4, 2)."""
    return ConstantVelocity(0.0).noise_gain(dt)


def cv_process_noise(dt: float, sigma_v: float) -> np.ndarray:
    """2-D NCV process noise Q = G Qv G^T (4, 4); sigma_v in m/s^2."""
    return ConstantVelocity(sigma_v).process_noise(dt).copy()


def position_measurement_matrix(n: int = 4) -> np.ndarray:
    """H = [I2 0] (2, n): positions are measured."""
    return np.eye(2, n)  # (4.77)-(4.79) H = [I 0], positions-first ordering (§1.2 [R])


def measurement_noise(sigma_w: float) -> np.ndarray:
    """R = sigma_w^2 I2 (2, 2); sigma_w in m."""
    return PositionMeasurement(sigma_w).R
