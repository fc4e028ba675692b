"""Scenario kind "convoy of point targets on a known road" (paper 000 §II, §IV), seeded, and its tracking loop.

C point cars drive one behind the other along the known flat road y = g(x) = a sin(w x) (paper 000 §IV:
y = sin(x) with x, y in km, i.e. a = 1000 m, w = 1e-3 rad/m; highway-env's SineLane with the same amplitude and
pulsation), with no manoeuvres and a constant gap. Car 0 is the rearmost, car c + 1 is `separation_m` (Euclidean
distance) ahead of car c; car `target` is tracked. A tower sees the road and returns one measurement of unknown
origin per step (sensors.mixed). Units: m, s (the paper's km values are converted).

Truth (paper 000 eqs. (34)-(37)): L = M/2 (xdot^2 + ydot^2), constraint omega(q) = [-g'(x), 1], so
    xddot = -g' g'' xdot^2 / (1 + g'^2),   yddot = g'' xdot^2 + g' xddot
(for g = sin: xddot = sin(2x) xdot^2 / (3 + cos 2x), the paper's lambda); speed along the road is conserved.
Integrated by RK4 at dt; then, per step, white acceleration N(0, sigma_a^2) on xddot ([D]: the paper's
"N[0, 0.0001]" read as a std in km/s^2, where it enters is not stated) and y = g(x), ydot = g'(x) xdot so the car
stays on the road [D].

Filter model (`RoadMotion`, for trackers' EKF): the same ODE without noise over one RK4 step, state [x, y, xdot,
ydot]; Jacobian: the exact derivative of that RK4 step (chain rule through its stages); Q = the truth's acceleration
noise mapped along the road tangent [D]. First-order EKF: at dt = 1e-4 s the f_xx terms of paper 000 eq. (4)
are negligible [D].

    SineRoad(amplitude, pulsation)                         g, dg, d2g, point(x) -> (..., 2)
    ConvoyScenario(...)                                    frozen, defaults = paper 000 / reference [D]
    integrate(q0 (..., 4), road, dt, steps, sigma_a, rng)  -> (steps + 1, ..., 4) truth states
    simulate(scn, seed)                                    -> ConvoyRun
    Association(gate, gamma, pd, pg)                       how the one measurement is used (paper 000 §III-B/C)
    track(run, scn, assoc)                                 -> ConvoyTrack (single-target loop, no management)

Random streams: SeedSequence(seed).spawn(4) -> truth noise, mixing mask, sensor noise, neighbour choice.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import brentq

from roadtrack.sensors.mixed import MIX_MODES, mixed_measurements, wrong_steps
from roadtrack.trackers.filters.kalman import ExtendedKalmanFilter
from roadtrack.trackers.gating import gate
from roadtrack.trackers.models import PositionMeasurement


# ------------------------------------------------------------------------------------------------ road
@dataclass(frozen=True)
class SineRoad:
    """y = amplitude sin(pulsation x) [m]; paper 000 §IV: y = sin(x) in km = 1000 sin(1e-3 x) in m."""

    amplitude: float = 1000.0
    pulsation: float = 1e-3

    def g(self, x):
        return self.amplitude * np.sin(self.pulsation * x)  # paper 000 §IV road g(x)

    def dg(self, x):
        return self.amplitude * self.pulsation * np.cos(self.pulsation * x)

    def d2g(self, x):
        return -self.amplitude * self.pulsation ** 2 * np.sin(self.pulsation * x)

    def point(self, x) -> np.ndarray:
        """(..., 2) road points (x, g(x))."""
        x = np.asarray(x, dtype=np.float64)
        return np.stack([x, self.g(x)], axis=-1)


def road_ode(q: np.ndarray, road: SineRoad) -> np.ndarray:
    """dq/dt (..., 4) of q = [x, y, xdot, ydot] (..., 4) on the road (real or complex)."""
    x, xd = q[..., 0], q[..., 2]
    g1, g2 = road.dg(x), road.d2g(x)
    out = np.empty_like(q)
    out[..., 0], out[..., 1] = xd, q[..., 3]
    out[..., 2] = xdd = -g1 * g2 * xd * xd / (1.0 + g1 * g1)  # paper 000 eqs. (34)-(37): lambda eliminated
    out[..., 3] = g2 * xd * xd + g1 * xdd  # paper 000 eq. (37): d^2/dt^2 (y - g(x)) = 0
    return out


def rk4_step(q: np.ndarray, dt: float, road: SineRoad) -> np.ndarray:
    """One classical Runge-Kutta step of `road_ode` (..., 4)."""
    k1 = road_ode(q, road)
    k2 = road_ode(q + 0.5 * dt * k1, road)
    k3 = road_ode(q + 0.5 * dt * k2, road)
    k4 = road_ode(q + dt * k3, road)
    return q + dt / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)


def _ode_scalar(q: tuple[float, ...], a: float, w: float) -> tuple[float, float, float, float]:
    """`road_ode` of one state in plain floats."""
    x, _, xd, yd = q
    g1, g2 = a * w * math.cos(w * x), -a * w * w * math.sin(w * x)
    xdd = -g1 * g2 * xd * xd / (1.0 + g1 * g1)  # paper 000 eqs. (34)-(37), as in road_ode
    return xd, yd, xdd, g2 * xd * xd + g1 * xdd


def _ode_jacobian(q: tuple[float, ...], a: float, w: float) -> np.ndarray:
    """d road_ode / dq (4, 4) at one state: only xddot and yddot depend on (x, xdot)."""
    x, _, xd, _ = q
    c, s = math.cos(w * x), math.sin(w * x)
    g1, g2, g3 = a * w * c, -a * w * w * s, -a * w ** 3 * c
    n = 1.0 + g1 * g1
    u = g1 * g2 / n  # xddot = -u xdot^2
    du = ((g2 * g2 + g1 * g3) * n - 2.0 * g1 * g1 * g2 * g2) / (n * n)
    xdd_x, xdd_v = -du * xd * xd, -2.0 * u * xd
    return np.array([[0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0], [xdd_x, 0.0, xdd_v, 0.0],
                     [g3 * xd * xd - g2 * u * xd * xd + g1 * xdd_x, 0.0, 2.0 * g2 * xd + g1 * xdd_v, 0.0]])


def _rk4_stages(q: tuple[float, ...], dt: float, a: float, w: float) -> tuple[list, list]:
    """Stage points and slopes of one RK4 step of one state."""
    pts, ks = [q], [_ode_scalar(q, a, w)]
    for h in (0.5 * dt, 0.5 * dt, dt):
        pts.append(tuple(qi + h * ki for qi, ki in zip(q, ks[-1])))
        ks.append(_ode_scalar(pts[-1], a, w))
    return pts, ks


def _rk4_scalar(q: tuple[float, ...], dt: float, a: float, w: float) -> tuple[float, ...]:
    """`rk4_step` of one state in plain floats (the filter's f; about 5 times faster than the array form)."""
    _, (k1, k2, k3, k4) = _rk4_stages(q, dt, a, w)
    return tuple(qi + dt / 6.0 * (b1 + 2.0 * b2 + 2.0 * b3 + b4) for qi, b1, b2, b3, b4 in zip(q, k1, k2, k3, k4))


def _rk4_jacobian(q: tuple[float, ...], dt: float, a: float, w: float) -> np.ndarray:
    """Exact Jacobian (4, 4) of the RK4 map by the chain rule through its stages: dk_i = A(q_i) (I + h_i dk_{i-1})."""
    pts, _ = _rk4_stages(q, dt, a, w)
    eye = np.eye(4)
    dk = [_ode_jacobian(pts[0], a, w)]
    for p, h in zip(pts[1:], (0.5 * dt, 0.5 * dt, dt)):
        dk.append(_ode_jacobian(p, a, w) @ (eye + h * dk[-1]))
    return eye + dt / 6.0 * (dk[0] + 2.0 * dk[1] + 2.0 * dk[2] + dk[3])  # paper 000 eq. (5): f_x


def on_road(x: np.ndarray, speed: float, road: SineRoad) -> np.ndarray:
    """States (..., 4) at abscissae x moving forward at `speed` [m/s] along the road."""
    x = np.asarray(x, dtype=np.float64)
    xd = speed / np.sqrt(1.0 + road.dg(x) ** 2)  # conserved: xdot^2 (1 + g'^2) = v^2
    return np.stack([x, road.g(x), xd, road.dg(x) * xd], axis=-1)


def integrate(q0: np.ndarray, road: SineRoad, dt: float, steps: int, sigma_a: float,
              rng: np.random.Generator | None) -> np.ndarray:
    """Truth (steps + 1, ..., 4) from q0 (..., 4): RK4, then N(0, sigma_a^2) on xddot held over the step (skipped
    when rng is None or sigma_a = 0), then y = g(x), ydot = g'(x) xdot [D]."""
    q = np.array(q0, dtype=np.float64)
    out = np.empty((steps + 1,) + q.shape)
    out[0] = q
    for k in range(steps):
        q = rk4_step(q, dt, road)
        if rng is not None and sigma_a > 0.0:
            a = sigma_a * rng.standard_normal(q.shape[:-1])  # paper 000 §IV: process noise added to the motion
            q[..., 0] += 0.5 * a * dt * dt
            q[..., 2] += a * dt
        q[..., 1], q[..., 3] = road.g(q[..., 0]), road.dg(q[..., 0]) * q[..., 2]  # stay on the road [D]
        out[k + 1] = q
    return out


# ------------------------------------------------------------------------------------- filter model
@dataclass(frozen=True)
class RoadMotion:
    """Motion model of a car on `road` for trackers' EKF: f = one RK4 step of the noise-free ODE (paper 000
    eqs. (34)-(37)); Q = sigma_a^2 G G^T with G = [dt^2/2, g' dt^2/2, dt, g' dt] (acceleration along x, carried
    onto the road tangent) [D]. State [x, y, xdot, ydot] [m, m/s]."""

    road: SineRoad = SineRoad()
    sigma_a: float = 0.1
    linear: bool = field(default=False, init=False)
    ndim = 4
    dims = 2
    position = (0, 1)
    velocity = (2, 3)

    def f(self, x: np.ndarray, dt: float) -> np.ndarray:
        q = tuple(float(v) for v in x)
        return np.array(_rk4_scalar(q, float(dt), self.road.amplitude, self.road.pulsation))  # paper 000 eq. (1)

    def jacobian(self, x: np.ndarray, dt: float) -> np.ndarray:
        """f_x (4, 4) of paper 000 eq. (5): the exact derivative of the RK4 step (chain rule through its stages)."""
        return _rk4_jacobian(tuple(float(v) for v in x), float(dt), self.road.amplitude, self.road.pulsation)

    def process_noise(self, dt: float, x: np.ndarray | None = None) -> np.ndarray:
        slope = 0.0 if x is None else float(self.road.dg(x[0]))
        G = np.array([0.5 * dt * dt, slope * 0.5 * dt * dt, dt, slope * dt])
        return self.sigma_a ** 2 * np.outer(G, G)  # paper 000 eq. (1): Q of v(k) [D]

    def embed(self, x: np.ndarray, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return np.asarray(x, dtype=np.float64), np.asarray(P, dtype=np.float64)


# ------------------------------------------------------------------------------------------ scenario
@dataclass(frozen=True)
class ConvoyScenario:
    """cars: convoy size (paper 000 §IV: 2); target: tracked car index; separation_m: Euclidean distance between
    consecutive cars at t = 0 [m]; speed_mps: speed along the road [D: 30 m/s]; dt [s] (paper: 1e-4 s); steps:
    measurements per run [I: about 1000]; sigma_m: sensor noise std per axis [m] (paper: 0.5 m); sigma_a: truth
    white acceleration on xddot [m/s^2] [D: 0.1]; fraction, mix_mode: share of wrong measurements (paper: 10 %,
    an exact count at random steps, sensors.mixed); wrong_at: explicit 0-based wrong steps instead (paper 000
    §V-C: 28, 59, ... 1-based); x0_m: abscissa of car 0 at t = 0 [m] [D]; p0_vel_std: velocity std of the initial
    estimate [m/s] [D: 0.001 km/s]; filter_sigma_a: the filter's Q (None: sigma_a)."""

    cars: int = 2
    target: int = 0
    separation_m: float = 10.0
    speed_mps: float = 30.0
    dt: float = 1e-4
    steps: int = 1000
    sigma_m: float = 0.5
    sigma_a: float = 0.1
    fraction: float = 0.10
    mix_mode: str = "fraction"
    wrong_at: tuple[int, ...] | None = None
    x0_m: float = 0.0
    p0_vel_std: float = 1.0
    road: SineRoad = SineRoad()
    filter_sigma_a: float | None = None

    def __post_init__(self) -> None:
        if not (isinstance(self.cars, int) and self.cars >= 1 and 0 <= self.target < self.cars):
            raise ValueError(f"ConvoyScenario needs cars >= 1 and 0 <= target < cars, got {self.cars}, {self.target}")
        if not (self.separation_m > 0 and self.speed_mps >= 0 and self.dt > 0 and self.sigma_m > 0
                and self.sigma_a >= 0 and self.p0_vel_std > 0 and isinstance(self.steps, int) and self.steps >= 1):
            raise ValueError("ConvoyScenario needs separation_m > 0, speed_mps >= 0, dt > 0, sigma_m > 0, "
                             "sigma_a >= 0, p0_vel_std > 0 and an int steps >= 1")
        if self.mix_mode not in MIX_MODES:
            raise ValueError(f"ConvoyScenario.mix_mode: unknown {self.mix_mode!r}; valid: {', '.join(MIX_MODES)}")
        if self.wrong_at is not None and any(not 0 <= k < self.steps for k in self.wrong_at):
            raise ValueError(f"ConvoyScenario.wrong_at: steps must lie in [0, {self.steps - 1}]")

    def initial_states(self) -> np.ndarray:
        """(cars, 4) true states at t = 0: car c + 1 at Euclidean distance separation_m ahead of car c [D]."""
        xs = [float(self.x0_m)]
        for _ in range(1, self.cars):
            p = self.road.point(xs[-1])
            gap = lambda x: float(np.hypot(*(self.road.point(x) - p))) - self.separation_m  # noqa: E731
            xs.append(brentq(gap, xs[-1], xs[-1] + self.separation_m))
        return on_road(np.array(xs), self.speed_mps, self.road)

    def initial_covariance(self) -> np.ndarray:
        """P0 = diag(R, p0_vel_std^2 I2) [D]."""
        return np.diag([self.sigma_m ** 2] * 2 + [self.p0_vel_std ** 2] * 2)

    def filter(self) -> ExtendedKalmanFilter:
        """trackers' EKF on `RoadMotion` with a position measurement, R = sigma_m^2 I2 (paper 000 §IV [R])."""
        qa = self.sigma_a if self.filter_sigma_a is None else self.filter_sigma_a
        return ExtendedKalmanFilter(motion=RoadMotion(self.road, qa), measurement=PositionMeasurement(self.sigma_m))


@dataclass(frozen=True, eq=False)
class ConvoyRun:
    """truth (K+1, C, 4) at t = k dt; z (K, 2) the measurement of step k = 1..K (row k-1); origin (K,) int64
    the car that produced it and wrong (K,) bool (scoring only); x0_est (4,), P0 (4, 4) initial estimate."""

    truth: np.ndarray
    z: np.ndarray
    origin: np.ndarray
    wrong: np.ndarray
    x0_est: np.ndarray
    P0: np.ndarray


def simulate(scn: ConvoyScenario, seed: int | np.random.SeedSequence) -> ConvoyRun:
    """One seeded run of `scn`; the filter starts at the target's true state [D]."""
    ss = seed if isinstance(seed, np.random.SeedSequence) else np.random.SeedSequence(seed)
    g_truth, g_mix, g_noise, g_pick = (np.random.default_rng(s) for s in ss.spawn(4))
    truth = integrate(scn.initial_states(), scn.road, scn.dt, scn.steps, scn.sigma_a, g_truth)
    if scn.wrong_at is not None:
        mask = np.zeros(scn.steps, dtype=bool)
        mask[list(scn.wrong_at)] = True
    else:
        mask = wrong_steps(scn.steps, scn.fraction, g_mix, scn.mix_mode)
    meas = mixed_measurements(truth[1:, :, :2], scn.target, scn.sigma_m, mask, g_noise, g_pick)
    return ConvoyRun(truth=truth, z=meas.z, origin=meas.origin, wrong=meas.wrong(scn.target),
                     x0_est=truth[0, scn.target].copy(), P0=scn.initial_covariance())


# ------------------------------------------------------------------------------------------ tracking
@dataclass(frozen=True)
class Association:
    """How the loop uses the one measurement of a step (paper 000 §III-B, §III-C, §V-B).

    gate: validate it only if d2 = nu' S^-1 nu <= gamma (eq. (10)); otherwise always validated.
    gamma: gate threshold; with gate=False it is only the reference gate that sets b (None: b = 0, i.e. beta_1 = 1,
    the plain EKF: "PDAF without gating", P_G = 1, V infinite [R]). pd, pg: P_D, P_G of the PDAF weights
    (eqs. (25)-(29)); the clutter density is the sample density lambda = m_k / V_k (eq. (27))."""

    gate: bool = True
    gamma: float | None = 9.0
    pd: float = 1.0
    pg: float = 0.971

    def __post_init__(self) -> None:
        if self.gate and self.gamma is None:
            raise ValueError("Association: a gate needs gamma")
        if self.gamma is not None and not self.gamma > 0:
            raise ValueError(f"Association.gamma must be > 0, got {self.gamma}")
        if not (0.0 < self.pd <= 1.0 and 0.0 < self.pg <= 1.0):
            raise ValueError(f"Association needs 0 < pd <= 1 and 0 < pg <= 1, got {self.pd}, {self.pg}")

    def b(self, m_k: int = 1, nz: int = 2) -> float:
        """b of eq. (29) for m_k validated measurements of dimension nz (0 without a reference gate).

        With lambda = m_k / V_k (eq. (27)) and V_k = c_nz gamma^(nz/2) |S|^(1/2) (eq. (30)), S cancels:
        b = m_k (2 pi / gamma)^(nz/2) (1 - P_D P_G) / (c_nz P_D). Reconstructed: the paper prints c_nz as a factor
        in (29); it is a divisor (eq. (28) gives it so). E.g. gamma 9, P_D 1, P_G 0.971: b = 0.00644."""
        if self.gamma is None or m_k == 0:
            return 0.0
        c = math.pi ** (0.5 * nz) / math.gamma(0.5 * nz + 1.0)  # volume of the unit nz-ball
        return m_k * (2.0 * math.pi / self.gamma) ** (0.5 * nz) * (1.0 - self.pd * self.pg) / (c * self.pd)  # eq. (29) [R]


@dataclass(frozen=True, eq=False)
class ConvoyTrack:
    """x (K+1, 4), P (K+1, 4, 4) estimates (index 0: the initial one); nu (K, 2) innovation of every measurement
    (also of those gated out); S (K, 2, 2); d2 (K,); validated (K,) bool; beta0 (K,) miss weight (1 if gated out)."""

    x: np.ndarray
    P: np.ndarray
    nu: np.ndarray
    S: np.ndarray
    d2: np.ndarray
    validated: np.ndarray
    beta0: np.ndarray


def pda_weights(assoc: Association, nu: np.ndarray, S: np.ndarray) -> tuple[float, bool, float, float]:
    """(d2, validated, beta_1, beta_0) of the one measurement: gate eq. (10), then PDAF eqs. (25)-(29).
    (The same weights as trackers.association.pda with clutter density m_k / V_k; written in the paper's b form
    here because one scalar step does not need the batched log-space machinery; tests check they agree.)"""
    d2 = float(nu @ np.linalg.solve(S, nu))  # paper 000 eq. (10) weighted norm (== trackers.gating.mahalanobis2)
    if assoc.gate and not gate(np.array([d2]), assoc.gamma)[0]:
        return d2, False, 0.0, 1.0  # paper 000 §III-B: dropped, keep predicting (eq. (19))
    b, e = assoc.b(1, len(nu)), math.exp(-0.5 * d2)  # paper 000 eqs. (25)-(29): e_i = exp(-d2 / 2)
    return d2, True, e / (b + e), b / (b + e)  # paper 000 eqs. (25)-(26), m_k = 1


def track(run: ConvoyRun, scn: ConvoyScenario, assoc: Association) -> ConvoyTrack:
    """Single-target EKF/PDAF loop over the run (paper 000 §III-A-C): predict, gate, weight, update."""
    flt = scn.filter()
    K = len(run.z)
    s = flt.initial_state(run.x0_est, run.P0)
    xs, Ps = np.empty((K + 1, 4)), np.empty((K + 1, 4, 4))
    xs[0], Ps[0] = s.x, s.P
    nus, Ss, d2s = np.empty((K, 2)), np.empty((K, 2, 2)), np.empty(K)
    valid, b0s = np.zeros(K, dtype=bool), np.ones(K)
    for k in range(K):
        s_pred = flt.predict(s, scn.dt)  # paper 000 eqs. (4)-(5)
        z_hat, S = flt.predicted_measurement(s_pred)  # paper 000 eq. (6)
        nu = run.z[k] - z_hat  # paper 000 eq. (8), nu = z - z_hat [R]
        d2s[k], valid[k], beta1, b0s[k] = pda_weights(assoc, nu, S)
        s = flt.update(s_pred, nu[None], np.array([beta1]), b0s[k]) if valid[k] else s_pred  # eqs. (20)-(21)
        xs[k + 1], Ps[k + 1], nus[k], Ss[k] = s.x, s.P, nu, S
    return ConvoyTrack(x=xs, P=Ps, nu=nus, S=Ss, d2=d2s, validated=valid, beta0=b0s)


def position_error(est: ConvoyTrack, run: ConvoyRun, target: int) -> np.ndarray:
    """(K+1,) Euclidean position error of the estimate against the target's truth [m] (paper 000 §V "radial")."""
    return np.hypot(*(est.x[:, :2] - run.truth[:, target, :2]).T)


def measurement_error(run: ConvoyRun, target: int) -> np.ndarray:
    """(K,) Euclidean error of the raw measurements against the target's truth [m] (Figs. 3-4 "raw")."""
    return np.hypot(*(run.z - run.truth[1:, target, :2]).T)
