"""Point target in clutter with a forced loss (paper 002 §VI-A): the abstract scenario kind of the KS track regime
detector, in 1-D (the paper's example) and in the plane.

A point target moves with white acceleration (variance q per axis, the paper's x(k+1) = F x + G w); a sensor
measures its position with noise variance r per axis and detects it with probability pd until scan `loss_at`,
never after (the forced loss, P_D = 0). Poisson clutter of density lambda is uniform in an interval (1-D) or a
square (2-D) centred on the filter's predicted measurement, of half width max(window_min, window_gates x the
gate's half width): clutter is uniform everywhere in the paper, and only the part some gate can see is drawn
(`covered` checks the detector's gates afterwards). One PDAF (trackers' KalmanFilter, PDA weights, chi-square
gate `gate`) tracks it from the truth with the clean steady-state covariance, keeps its P_D through the loss
(the filter is not told) and never deletes the track.

The tracking part must not lose the target [R]: the paper keeps tracks whose truth measurement "never fails to
gate for more than 5 timesteps"; in the PDAF's own gate that also holds for a diverged track (its gate grows
to hundreds of units and still holds the target), so the truth is gated in the NOMINAL gate (clean steady-state
S, the gate of a track on its target). A tracking part that fails is drawn again from the next seed of the run's
SeedSequence (`attempts` counts them); only the accepted draw continues through the loss.

API
    ForcedLoss(...)                    the scenario (paper_1d(), plane_2d() presets)
    simulate(scn, seed) -> LossRun     one accepted run: S (K, m, m), d2 of every measurement, gate volumes
    LossRun.series(cfg, lam=None)      the KS regime detector over the run (trackers.trackloss.regime)
    LossRun.window(k, n)               one window ending at scan k, for assess_window
    covered(run, series)               (K,) bool: the detector's gates at scan k lay inside the drawn clutter
Random streams per draw: SeedSequence(seed).spawn(max_attempts)[i].spawn(4) -> truth noise, detection,
measurement noise, clutter. Scan k (0-based) is at t = (k + 1) dt.
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
from scipy.linalg import solve_discrete_are

from roadtrack.trackers.association import AssociationParams, pda
from roadtrack.trackers.filters import KalmanFilter
from roadtrack.trackers.gating import gate_probability, mahalanobis2_and_log_gaussian
from roadtrack.trackers.models import ConstantVelocity, PositionMeasurement
from roadtrack.trackers.tracker import gate_volume
from roadtrack.trackers.trackloss.regime import (RegimeConfig, RegimeSeries, constant_gate_scale, regime_series)


@dataclass(frozen=True)
class ForcedLoss:
    """dims: 1 or 2 position axes; dt [s]; q: white-acceleration variance per axis (the paper's Q = q, G = [dt^2/2,
    dt]); r: measurement noise variance per axis; clutter_density lambda [1/unit^dims]; gate: chi-square
    threshold gamma of the PDAF; pd: detection probability before the loss (also the filter's P_D);
    tracking_steps scans, then lost_steps scans with P_D = 0; window_min, window_gates: clutter half width;
    max_misses: scans in a row the truth may miss the nominal gate; max_attempts: draws of the tracking part."""

    dims: int = 1
    dt: float = 0.1
    q: float = 500.0
    r: float = 0.5
    clutter_density: float = 0.2
    gate: float = 16.0
    pd: float = 1.0
    tracking_steps: int = 1000
    lost_steps: int = 1000
    window_min: float = 200.0
    window_gates: float = 1.5
    max_misses: int = 5
    max_attempts: int = 5000

    def __post_init__(self) -> None:
        if self.dims not in (1, 2):
            raise ValueError(f"ForcedLoss.dims must be 1 or 2, got {self.dims!r}")
        if not (self.dt > 0 and self.q >= 0 and self.r > 0 and self.clutter_density > 0 and self.gate > 0
                and 0 < self.pd <= 1 and self.tracking_steps >= 1 and self.lost_steps >= 0):
            raise ValueError(f"ForcedLoss needs dt, r, clutter_density, gate > 0, q >= 0, pd in (0, 1], "
                             f"tracking_steps >= 1, lost_steps >= 0; got {self}")

    @property
    def steps(self) -> int:
        return self.tracking_steps + self.lost_steps

    @property
    def loss_at(self) -> int:
        """First scan (0-based) without the target's measurement."""
        return self.tracking_steps

    def filter(self) -> KalmanFilter:
        return KalmanFilter(ConstantVelocity(math.sqrt(self.q), self.dims), PositionMeasurement(math.sqrt(self.r),
                                                                                                self.dims))


def paper_1d(**overrides) -> ForcedLoss:
    """Paper 002 §VI-A: delta 0.1, lambda 0.2, q 500, r 0.5, gamma 16, P_D 1, 1000 + 1000 scans."""
    return ForcedLoss(**overrides)


def plane_2d(**overrides) -> ForcedLoss:
    """The same target in the plane, lambda 0.03 per unit^2 so the nominal gate holds as much clutter as the
    paper's (lambda V = 1.7) [D]."""
    return ForcedLoss(**{"dims": 2, "clutter_density": 0.03, "window_min": 40.0, **overrides})


@dataclass(frozen=True, eq=False)
class LossRun:
    """One accepted run of K scans: truth (K, dims) target positions; z_hat (K, m) predictions; S (K, m, m);
    root_det (K,) |S|^(1/2); volume (K,) the PDAF's gate volumes; d2 (N,) squared Mahalanobis distances of every
    measurement (scan k's in d2[offsets[k]:offsets[k + 1]], the target's first when detected); n_gated (K,);
    truth_gated (K,) the target's measurement in the nominal gate (False when not detected); half_width (K,) of
    the clutter window; pd (K,) the filter's P_D (the detector's); attempts: draws of the tracking part."""

    scenario: ForcedLoss
    truth: np.ndarray
    z_hat: np.ndarray
    S: np.ndarray
    root_det: np.ndarray
    volume: np.ndarray
    d2: np.ndarray
    offsets: np.ndarray
    n_gated: np.ndarray
    truth_gated: np.ndarray
    half_width: np.ndarray
    pd: np.ndarray
    attempts: int

    def series(self, cfg: RegimeConfig, lam: float | None = None, gamma: float | None = None,
               upto: int | None = None) -> RegimeSeries:
        """The KS regime detector over the run's first `upto` scans (None: all), with the filter's P_D and clutter
        density lam (default: the scenario's, i.e. lambda_theory = lambda_actual)."""
        lam = self.scenario.clutter_density if lam is None else lam
        K = len(self.root_det) if upto is None else upto
        return regime_series(self.root_det[:K], self.d2[:self.offsets[K]], self.offsets[:K + 1], self.pd[:K], lam,
                             self.scenario.dims, cfg, gamma)

    def window(self, k: int, n: int) -> tuple[np.ndarray, list[np.ndarray], np.ndarray]:
        """(root_det (n,), d2_scans (n arrays), pd (n,)) of scans k - n + 1..k, for regime.assess_window."""
        a = k + 1 - n
        if a < 0:
            raise ValueError(f"window of {n} scans ending at scan {k} starts before scan 0")
        scans = [self.d2[self.offsets[j]:self.offsets[j + 1]] for j in range(a, k + 1)]
        return self.root_det[a:k + 1], scans, self.pd[a:k + 1]


@functools.lru_cache(maxsize=16)
def steady_state(scn: ForcedLoss) -> tuple[np.ndarray, np.ndarray]:
    """Clean Kalman steady state (P_D = 1, no clutter): the updated covariance P (2d, 2d) and S (d, d), from the
    discrete algebraic Riccati equation of the predicted covariance."""
    flt = scn.filter()
    A, Q = flt.motion.transition(scn.dt), flt.motion.process_noise(scn.dt)
    H, R = flt.measurement.matrix(flt.motion), flt.measurement.R
    P_pred = solve_discrete_are(A.T, H.T, Q, R)
    S = H @ P_pred @ H.T + R
    K = P_pred @ H.T @ np.linalg.inv(S)
    P = P_pred - K @ S @ K.T
    return 0.5 * (P + P.T), S


def simulate(scn: ForcedLoss, seed: int | np.random.SeedSequence) -> LossRun:
    """One accepted run (module docstring): draws of the tracking part until one keeps the target, then the loss."""
    ss = seed if isinstance(seed, np.random.SeedSequence) else np.random.SeedSequence(seed)
    P0, S_ref = steady_state(scn)
    for attempt, child in enumerate(ss.spawn(scn.max_attempts), start=1):
        out = _draw(scn, child, P0, S_ref)
        if out is not None:
            return LossRun(scenario=scn, attempts=attempt, **out)
    raise RuntimeError(f"no tracking part of {scn.tracking_steps} scans kept the target in {scn.max_attempts} draws")


def _draw(scn: ForcedLoss, ss: np.random.SeedSequence, P0: np.ndarray, S_ref: np.ndarray) -> dict | None:
    """One closed-loop draw: None as soon as the tracking part loses the target (nominal gate, max_misses)."""
    g_truth, g_det, g_noise, g_clutter = (np.random.default_rng(s) for s in ss.spawn(4))
    d, K, flt = scn.dims, scn.steps, scn.filter()
    A, G = flt.motion.transition(scn.dt), flt.motion.noise_gain(scn.dt)
    x = np.zeros(2 * d)
    s = flt.initial_state(x, P0)
    params = AssociationParams(pd=scn.pd, pg=gate_probability(scn.gate, d), clutter_density=scn.clutter_density)
    S_ref_inv = np.linalg.inv(S_ref)
    cols = {k: [] for k in ("truth", "z_hat", "S", "volume", "d2", "n_gated", "truth_gated", "half_width")}
    misses = 0
    for k in range(K):
        x = A @ x + G @ (g_truth.normal(size=d) * math.sqrt(scn.q))  # paper 002 §VI-A truth model
        detected = (g_det.random() < scn.pd) and k < scn.loss_at  # forced loss: P_D = 0 from loss_at
        z_true = x[:d] + g_noise.normal(size=d) * math.sqrt(scn.r)
        s_pred = flt.predict(s, scn.dt)
        z_hat, S = flt.predicted_measurement(s_pred)
        half = max(scn.window_min, scn.window_gates * math.sqrt(scn.gate * float(np.linalg.eigvalsh(S)[-1])))
        n_c = g_clutter.poisson(scn.clutter_density * (2.0 * half) ** d)
        clutter = z_hat + g_clutter.uniform(-half, half, size=(n_c, d))
        Z = np.vstack([z_true[None], clutter]) if detected else clutter
        nu = Z - z_hat
        d2, log_lik = mahalanobis2_and_log_gaussian(nu[None], S[None])
        gated = d2 <= scn.gate
        W, w0 = pda(log_lik, gated, params)
        use = gated[0]
        s = flt.update(s_pred, nu[use], W[0, use], float(w0[0]))
        e = z_true - z_hat
        in_nominal = bool(detected and e @ S_ref_inv @ e <= scn.gate)
        misses = 0 if in_nominal else misses + 1
        if k < scn.loss_at and misses > scn.max_misses:
            return None
        for name, v in (("truth", x[:d].copy()), ("z_hat", z_hat), ("S", S), ("d2", d2[0]),
                        ("volume", float(gate_volume(S[None], scn.gate)[0])), ("n_gated", int(use.sum())),
                        ("truth_gated", in_nominal), ("half_width", half)):
            cols[name].append(v)
    return _pack(cols, scn)


def _pack(cols: dict, scn: ForcedLoss) -> dict:
    S = np.array(cols["S"]).reshape(-1, scn.dims, scn.dims)
    sizes = np.array([a.size for a in cols["d2"]], dtype=np.int64)
    return dict(truth=np.array(cols["truth"]), z_hat=np.array(cols["z_hat"]), S=S,
                root_det=np.sqrt(np.linalg.det(S)), volume=np.array(cols["volume"]), d2=np.concatenate(cols["d2"]),
                offsets=np.concatenate([[0], np.cumsum(sizes)]), n_gated=np.array(cols["n_gated"], dtype=np.int64),
                truth_gated=np.array(cols["truth_gated"], dtype=bool), half_width=np.array(cols["half_width"]),
                pd=np.full(len(S), scn.pd))


def covered(run: LossRun, series: RegimeSeries) -> np.ndarray:
    """(K,) bool: at each scan with a verdict, every NG and CG gate of its window lies inside the clutter drawn at
    that scan (gate half extent sqrt(threshold x largest eigenvalue of S) <= half width); True where no verdict."""
    top = np.linalg.eigvalsh(run.S)[:, -1]
    ok = np.ones(len(run.root_det), dtype=bool)
    for k in np.flatnonzero(series.n > 0):
        n = int(series.n[k])
        a = k + 1 - n
        s = constant_gate_scale(run.root_det[a:k + 1], series.sigma_n[k], run.scenario.dims)
        thr = series.gamma[k] * np.maximum(1.0, 1.0 / s)  # the larger of the NG and CG thresholds
        ok[k] = bool(np.all(np.sqrt(thr * top[a:k + 1]) <= run.half_width[a:k + 1]))
    return ok
