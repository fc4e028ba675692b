"""Seeded single-target simulations for the thesis's abstract studies (no highway-env, no LiDAR).

A point target moves in the plane with state [px, py, vx, vy] (m, m/s) through a sequence of `Segment`s:
near-constant velocity (NCV) with white-acceleration noise, coordinated turns with a known rate omega
(deterministic arcs: the upper-left 4 x 4 block of A_CT(omega), thesis §1.3), and injected model
errors (the truth uses a_scale * A, thesis §2.1.6 "2 % change in the system matrix", or scales the Ts entries
of A, thesis (3.74)); the filters always keep their nominal model. A sensor reports the position with noise
sigma_w, detects the target with probability pd, and adds Poisson clutter of density lambda [1/m^2], uniform in
a square window of half side `clutter_half_width` [m] centred on the TRUE target position at each scan (default
10 sigma_w: it covers a chi-square gate of alpha = 16 for an innovation covariance up to about 6 sigma_w^2;
clutter outside the window is not simulated, so a filter that has lost the target sees an empty scene).

API
    Segment(steps, omega=0.0, a_scale=1.0, ts_scale=1.0, process_noise=None)
    Scenario(x0, segments, dt, sigma_v, sigma_w, pd=1.0, clutter_density=0.0, clutter_half_width=None,
             p0_std=None, perturb_init=False)
    curve(duration, dt, heading_change), cut_in_out(duration, dt, speed, offset), u_turn(duration, dt)
                                         -> tuple[Segment, ...]   manoeuvre shapes of thesis §4.6.1 [D]
    from_timeline(x0, dt, ((t_end, kind), ...), heading_change, offset) -> tuple[Segment, ...]
                                         a thesis timeline (e.g. Table 4.1) as segments
    simulate(scn, seed) -> Run           truth (K+1, 4), Z[k] (M_k, 2) and origin[k] (M_k,) bool for scans
                                         k = 1..K (list index k-1); x0_est (4,), P0 (4, 4) initial estimate
    track(run, scn, flt, associator="pda", association=None) -> Estimates
                                         single-target loop from (x0_est, P0), no track management:
                                         predict -> gate -> associate (trackers.association ASSOCIATORS)
                                         -> update; x (K+1, n), P (K+1, n, n), info name -> (K, d) (NaN where
                                         the filter did not update), n_gated (K,), w0 (K,)
    monte_carlo(scn, filters, n_runs, seed, associator="pda", association=None) -> dict name -> MonteCarlo
                                         every filter sees the same n_runs simulated runs
    MonteCarlo.errors (R, K+1, 4) estimate - truth; .rmse(steps, runs) (4,); .lost(threshold) (R,) bool;
    .info name -> (R, K, d)
    lost_at(err, threshold, min_steps=5) -> int | None
                                         first scan from which the error stays above threshold to the end
                                         (a tail of at least min_steps scans: "lost target")

Random streams: `SeedSequence(seed).spawn(5)` -> truth noise, detection, measurement noise, clutter, initial
estimate; each is drawn every scan whatever the others do, so adding clutter or lowering pd does not change
the truth or the sensor noise. Time: scan k is at t = k dt [s].
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Mapping

import numpy as np
from scipy.optimize import brentq

from roadtrack.trackers.association.roles import AssociationInput, build_associator
from roadtrack.trackers.gating import gate, mahalanobis2_and_log_gaussian
from roadtrack.trackers.models import ConstantVelocity, CoordinatedTurn
from roadtrack.trackers.tracker import gate_volume


# ------------------------------------------------------------------------------------------ scenario
@dataclass(frozen=True)
class Segment:
    """`steps` scans of one motion: omega [rad/s] known turn rate (0: NCV); a_scale: the truth uses
    a_scale * A (model error of thesis §2.1.6 / §2.2.6); ts_scale: the Ts entries of A become Ts * ts_scale
    (thesis (3.74), NCV only); process_noise: add white acceleration (None: only when omega == 0)."""

    steps: int
    omega: float = 0.0
    a_scale: float = 1.0
    ts_scale: float = 1.0
    process_noise: bool | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.steps, int) or self.steps < 0:
            raise ValueError(f"Segment.steps must be an int >= 0, got {self.steps!r}")
        if self.ts_scale != 1.0 and self.omega != 0.0:
            raise ValueError("Segment.ts_scale applies to NCV segments only (omega == 0)")

    def transition(self, dt: float) -> np.ndarray:
        """Truth transition (4, 4) for one scan of `dt` seconds."""
        if self.omega == 0.0:
            A = ConstantVelocity(0.0).transition(dt * self.ts_scale)  # (3.74): Ts entries scaled
        else:
            A = CoordinatedTurn(0.0).transition(dt, self.omega)[:4, :4]  # thesis §1.3 [R] truth: known turn rate
        return self.a_scale * A

    @property
    def noisy(self) -> bool:
        return self.omega == 0.0 if self.process_noise is None else bool(self.process_noise)


@dataclass(frozen=True)
class Scenario:
    """x0 (4,) true initial state [m, m, m/s, m/s]; segments run in order; dt [s] scan period; sigma_v [m/s^2]
    truth white acceleration; sigma_w [m] position noise; pd detection probability; clutter_density [1/m^2];
    clutter_half_width [m] (None: 10 sigma_w); p0_std (position std [m], velocity std [m/s]) of the initial
    estimate's covariance P0 (None: sigma_w and sqrt(2) sigma_w / dt, two-point differencing); perturb_init:
    draw the initial estimate from N(x0, P0) instead of starting at the truth."""

    x0: tuple[float, float, float, float]
    segments: tuple[Segment, ...]
    dt: float
    sigma_v: float
    sigma_w: float
    pd: float = 1.0
    clutter_density: float = 0.0
    clutter_half_width: float | None = None
    p0_std: tuple[float, float] | None = None
    perturb_init: bool = False

    def __post_init__(self) -> None:
        if len(self.x0) != 4 or not all(math.isfinite(v) for v in self.x0):
            raise ValueError(f"Scenario.x0 must be 4 finite numbers, got {self.x0}")
        if not (self.dt > 0 and self.sigma_v >= 0 and self.sigma_w > 0 and 0 <= self.pd <= 1
                and self.clutter_density >= 0):
            raise ValueError("Scenario needs dt > 0, sigma_v >= 0, sigma_w > 0, 0 <= pd <= 1, clutter_density >= 0")

    @property
    def steps(self) -> int:
        return sum(s.steps for s in self.segments)

    @property
    def window(self) -> float:
        return 10.0 * self.sigma_w if self.clutter_half_width is None else self.clutter_half_width

    def initial_covariance(self) -> np.ndarray:
        ps, vs = (self.sigma_w, math.sqrt(2.0) * self.sigma_w / self.dt) if self.p0_std is None else self.p0_std
        return np.diag([ps ** 2, ps ** 2, vs ** 2, vs ** 2])


def curve(duration: float, dt: float, heading_change: float = math.radians(10.0)) -> tuple[Segment, ...]:
    """'Straight line and curve' (thesis §4.6.1, geometry [D]): one arc turning `heading_change` [rad]."""
    steps = round(duration / dt)
    return (Segment(steps, omega=heading_change / (steps * dt)),)


def cut_in_out(duration: float, dt: float, speed: float, offset: float = 3.5) -> tuple[Segment, ...]:
    """'Cut-in-out' (§9.x [D]): four arcs +w, -w, -w, +w of duration/4 each, peak lateral offset `offset` [m]
    at `speed` [m/s]: offset = 2 (speed / w) (1 - cos(w duration / 4))."""
    q = round(duration / dt / 4)
    D = 4 * q * dt
    w = brentq(lambda w: 2.0 * speed / w * (1.0 - math.cos(w * D / 4)) - offset, 1e-12, 0.999 * 4 * math.pi / D)
    return (Segment(q, omega=w), Segment(2 * q, omega=-w), Segment(q, omega=w))


def u_turn(duration: float, dt: float) -> tuple[Segment, ...]:
    """U-turn (§9.x [D]): one arc of pi rad."""
    return curve(duration, dt, math.pi)


def from_timeline(x0: tuple[float, ...], dt: float, spec: tuple[tuple[float, str], ...],
                  heading_change: float = math.radians(10.0), offset: float = 3.5) -> tuple[Segment, ...]:
    """Segments from a thesis-style timeline: spec = ((t_end [s], kind), ...), each piece running from the
    previous t_end (0 first) to its own; kind in "ncv", "curve" (heading_change [rad]), "cut_in_out" (peak
    lateral offset [m], at the speed |v0| of x0), "u_turn". E.g. thesis Table 4.1 car 1:
    ((93, "ncv"), (139, "curve"), (500, "ncv"))."""
    speed, out, t0 = math.hypot(x0[2], x0[3]), [], 0.0
    for t_end, kind in spec:
        d = t_end - t0
        if kind == "ncv":
            out.append(Segment(round(d / dt)))
        elif kind == "curve":
            out.extend(curve(d, dt, heading_change))
        elif kind == "cut_in_out":
            out.extend(cut_in_out(d, dt, speed, offset))
        elif kind == "u_turn":
            out.extend(u_turn(d, dt))
        else:
            raise ValueError(f"unknown timeline kind {kind!r}; allowed: ncv, curve, cut_in_out, u_turn")
        t0 = t_end
    return tuple(out)


# ------------------------------------------------------------------------------------------ simulation
@dataclass(frozen=True, eq=False)
class Run:
    """truth (K+1, 4) at t = 0..K dt; Z[k-1] (M_k, 2) measurements of scan k; origin[k-1] (M_k,) True for the
    target's own detection (scoring only); x0_est (4,), P0 (4, 4): the filters' initial estimate."""

    truth: np.ndarray
    Z: tuple[np.ndarray, ...]
    origin: tuple[np.ndarray, ...]
    x0_est: np.ndarray
    P0: np.ndarray


def simulate(scn: Scenario, seed: int | np.random.SeedSequence) -> Run:
    """One seeded run of `scn` (see the module docstring for the random streams)."""
    ss = seed if isinstance(seed, np.random.SeedSequence) else np.random.SeedSequence(seed)
    g_truth, g_det, g_noise, g_clutter, g_init = (np.random.default_rng(s) for s in ss.spawn(5))
    dt, K = scn.dt, scn.steps
    G = ConstantVelocity(0.0).noise_gain(dt)
    X = np.zeros((K + 1, 4))
    X[0] = scn.x0
    k = 0
    for seg in scn.segments:
        A = seg.transition(dt)
        for _ in range(seg.steps):
            v = g_truth.normal(size=2) * scn.sigma_v
            X[k + 1] = A @ X[k] + (G @ v if seg.noisy else 0.0)
            k += 1
    w, lam = scn.window, scn.clutter_density
    Z, origin = [], []
    for k in range(1, K + 1):
        detected = g_det.random() < scn.pd
        noise = g_noise.normal(size=2) * scn.sigma_w
        n_c = g_clutter.poisson(lam * (2.0 * w) ** 2)
        clutter = X[k, :2] + g_clutter.uniform(-w, w, size=(n_c, 2))
        z = np.vstack([X[k, :2] + noise, clutter]) if detected else clutter
        Z.append(z.reshape(-1, 2))
        origin.append(np.r_[np.ones(int(detected), dtype=bool), np.zeros(n_c, dtype=bool)])
    P0 = scn.initial_covariance()
    x0 = np.array(scn.x0, dtype=np.float64)
    draw = g_init.multivariate_normal(np.zeros(4), P0)
    if scn.perturb_init:
        x0 = x0 + draw
    return Run(truth=X, Z=tuple(Z), origin=tuple(origin), x0_est=x0, P0=P0)


# ------------------------------------------------------------------------------------------ tracking
@dataclass(frozen=True, eq=False)
class Estimates:
    """x (K+1, n) and P (K+1, n, n) filter outputs (index 0: the initial estimate); info: the filter's
    per-update diagnostics, name -> (K, d), NaN on scans without an update; n_gated (K,); w0 (K,)."""

    x: np.ndarray
    P: np.ndarray
    info: dict[str, np.ndarray]
    n_gated: np.ndarray
    w0: np.ndarray


def track(run: Run, scn: Scenario, flt, associator: str = "pda", association: Mapping | None = None) -> Estimates:
    """Run filter `flt` with one associator over `run` from its initial estimate (no track management).
    association: the associator's parameter table (gate_alpha, pd, clutter_density, ...); pd and
    clutter_density default to the scenario's (a clutter-free scenario uses lambda = 1e-9 1/m^2)."""
    table = {"pd": scn.pd if scn.pd > 0 else 1e-3, "clutter_density": scn.clutter_density or 1e-9,
             **dict(association or {})}
    kind, params = build_associator(associator, table, "associator")
    meas, m = flt.measurement, flt.measurement.ndim
    alpha = params.gate_alpha
    pg = params.gate_probability(m)
    s = flt.initial_state(run.x0_est, run.P0)
    x0, P0 = flt.output(s)
    K = len(run.Z)
    xs, Ps = np.zeros((K + 1, x0.size)), np.zeros((K + 1, x0.size, x0.size))
    xs[0], Ps[0] = x0, P0
    infos: list[dict] = []
    n_gated, w0s = np.zeros(K), np.zeros(K)
    for k, Z in enumerate(run.Z):
        s_pred = flt.predict(s, scn.dt)
        z_hat, S = flt.predicted_measurement(s_pred)
        nu = meas.residual(Z[None, :, :], z_hat[None, None, :])  # (1, M, m)
        d2, log_lik = mahalanobis2_and_log_gaussian(nu, S[None])
        lay = flt.layer(s_pred)
        inp = AssociationInput(log_lik=log_lik, gated=gate(d2, alpha), d2=d2, nu=nu, S=S[None],
                               pd=np.array([params.pd]), pg=pg, gate_volume=gate_volume(S[None], alpha),
                               layers=np.full((1, m), np.nan) if lay is None else np.asarray(lay)[None])
        out = kind.run(inp, params)
        W, w0 = np.asarray(out[0])[0], float(np.asarray(out[1])[0])
        use = W > 0.0
        s = flt.update(s_pred, nu[0, use], W[use], w0)
        xs[k + 1], Ps[k + 1] = flt.output(s)
        infos.append(dict(s.info))
        n_gated[k], w0s[k] = inp.gated.sum(), w0
    return Estimates(x=xs, P=Ps, info=_stack(infos), n_gated=n_gated, w0=w0s)


def _stack(infos: list[dict]) -> dict[str, np.ndarray]:
    sizes: dict[str, int] = {}
    for d in infos:
        for name, v in d.items():
            sizes[name] = np.size(v)
    out = {name: np.full((len(infos), n), np.nan) for name, n in sizes.items()}
    for k, d in enumerate(infos):
        for name, v in d.items():
            out[name][k] = np.ravel(v)
    return out


# ------------------------------------------------------------------------------------------ metrics
def lost_at(err: np.ndarray, threshold: float, min_steps: int = 5) -> int | None:
    """First scan k from which err[k:] > threshold to the end of the run, if that tail is at least `min_steps`
    scans long (err (K+1,), e.g. position error [m]); None if the target is not lost."""
    err = np.asarray(err)
    below = np.flatnonzero(err <= threshold)
    k = 0 if below.size == 0 else int(below[-1]) + 1
    return k if len(err) - k >= min_steps else None


@dataclass(frozen=True, eq=False)
class MonteCarlo:
    """errors (R, K+1, 4): estimate minus truth over R runs; info name -> (R, K, d) filter diagnostics."""

    errors: np.ndarray
    info: dict[str, np.ndarray] = field(default_factory=dict)

    def rmse(self, steps: slice = slice(1, None), runs: np.ndarray | None = None) -> np.ndarray:
        """RMSE per state (4,) [m, m, m/s, m/s] over the given scans and runs (default: all runs, scans 1..K)."""
        e = self.errors if runs is None else self.errors[runs]
        return np.sqrt(np.mean(e[:, steps] ** 2, axis=(0, 1)))  # thesis §10.1 RMSE over runs and scans

    def position_error(self) -> np.ndarray:
        """(R, K+1) Euclidean position error [m]."""
        return np.hypot(self.errors[..., 0], self.errors[..., 1])

    def lost(self, threshold: float, min_steps: int = 5) -> np.ndarray:
        """(R,) bool: the position error exceeds `threshold` [m] for the last `min_steps` scans or more (lost_at)."""
        return np.array([lost_at(e, threshold, min_steps) is not None for e in self.position_error()])


def monte_carlo(scn: Scenario, filters: Mapping[str, object], n_runs: int, seed: int, associator: str = "pda",
                association: Mapping | None = None) -> dict[str, MonteCarlo]:
    """Every filter in `filters` (name -> filter) over the same `n_runs` runs, seeded by SeedSequence(seed)."""
    runs = [simulate(scn, ss) for ss in np.random.SeedSequence(seed).spawn(n_runs)]
    out = {}
    for name, flt in filters.items():
        ests = [track(r, scn, flt, associator, association) for r in runs]
        errors = np.stack([e.x[:, :4] - r.truth for e, r in zip(ests, runs)])
        widths = {k: v.shape[1] for e in ests for k, v in e.info.items()}
        info = {k: np.stack([e.info.get(k, np.full((len(r.Z), d), np.nan)) for e, r in zip(ests, runs)])
                for k, d in sorted(widths.items())}
        out[name] = MonteCarlo(errors=errors, info=info)
    return out
