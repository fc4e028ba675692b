"""Scenario kind: N point targets on a line (1-D), constant velocity, crossing each other (paper 003 §IV).

Truth: x(t) = x_0 + v t for each target, no process noise (paper 003 eq. (1) with Q = 0); state
[x_1..x_N, v_1..v_N] [m, m/s]. Scan k = 1..steps is at t = k dt [s]; the estimate starts at t = 0 from x0_est
with covariance diag(p0_diag). The sensor (sensors.symmetric) adds N(0, sigma^2) to every position; a symmetric
sensor then reports sum of powers or sum of products of those same noisy positions, so the associated KF and
both symmetric EKFs of one run see the same noise.

Paper defaults (`paper_scenario`):
    x0 = [3, 25, 120, 10, 5, 0]   reconstructed: the printed "X = 3251201050" read in plain digit order; all
                                  three pairs then cross within 20 s (4.4, 11.7 and 19.0 s), as the paper says
    x0_est = 0, dt = 0.01 s, steps = 2000 (20 s), sigma = 5 m     (paper 003 §IV)
    p0_diag = [9, 625, 14400, 100, 25, 1]   [D]: the printed P0 is undecodable; these are the squared initial
                                  errors (1 for the stationary target). The position entries MUST differ: with
                                  x0_est = 0 and equal entries the EKF keeps all slots equal forever.
N = 2 uses the first two targets: x0 = [3, 25, 10, 5], p0_diag = [9, 625, 100, 25] [D] (crossing at 4.4 s).

Random streams: run r draws its noise from `SeedSequence(seed).spawn(n_runs)[r]`, so the first runs of a
short Monte Carlo are the first runs of a long one.

API
    LineTargets(x0, p0_diag, dt, steps, sigma, x0_est); paper_scenario(n_targets, steps)
    simulate(scn, n_runs, seed) -> LineRuns      truth (K + 1, 2N), z (R, K, N); .symmetric(form) -> y (R, K, N)
    track_symmetric(scn, runs, form, P0=None)    SME EKF (trackers.sme), all runs in one batch: (R, K + 1, 2N)
    track_associated(scn, runs, P0=None)         the core's KalmanFilter on z: (R, K + 1, 2N)
    labelled(est, truth) -> (est, perm)          per-step labelling by the permutation of minimum squared error
    position_rmse, diverged, label_exchanges     scores over runs
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from roadtrack.sensors.symmetric import SymmetricSensor, associated_positions
from roadtrack.trackers.filters import KalmanFilter
from roadtrack.trackers.models import ConstantVelocity, PositionMeasurement
from roadtrack.trackers.sme import SMETracker, SymmetricMeasurement, label_permutation, relabel

PAPER_X0 = (3.0, 25.0, 120.0, 10.0, 5.0, 0.0)
PAPER_P0_DIAG = (9.0, 625.0, 14400.0, 100.0, 25.0, 1.0)


@dataclass(frozen=True)
class LineTargets:
    """x0 (2N,) truth at t = 0 [m, m/s]; dt [s]; steps (scans); sigma [m] raw position noise; x0_est (2N,) the
    filters' initial estimate (None: zeros); p0_diag (2N,) the diagonal of the initial covariance [m^2, m^2/s^2]."""

    x0: tuple[float, ...]
    p0_diag: tuple[float, ...]
    dt: float = 0.01
    steps: int = 2000
    sigma: float = 5.0
    x0_est: tuple[float, ...] | None = None

    def __post_init__(self) -> None:
        n = len(self.x0)
        if n not in (4, 6):
            raise ValueError(f"LineTargets.x0 must hold [x_1..x_N, v_1..v_N] for N = 2 or 3, got {n} values")
        for name, v in (("p0_diag", self.p0_diag), ("x0_est", self.x0_est)):
            if v is not None and len(v) != n:
                raise ValueError(f"LineTargets.{name} must have {n} values like x0, got {len(v)}")
        if not all(math.isfinite(v) for v in self.x0) or not all(math.isfinite(v) and v > 0 for v in self.p0_diag):
            raise ValueError("LineTargets needs a finite x0 and p0_diag entries > 0")
        if not (self.dt > 0 and self.sigma > 0 and isinstance(self.steps, int) and self.steps >= 1):
            raise ValueError(f"LineTargets needs dt > 0, sigma > 0 and steps >= 1, got {self.dt}, {self.sigma}, "
                             f"{self.steps}")

    @property
    def n_targets(self) -> int:
        return len(self.x0) // 2

    @property
    def times(self) -> np.ndarray:
        """t_k = k dt for k = 0..steps (steps + 1,) [s]."""
        return np.arange(self.steps + 1) * self.dt

    @property
    def initial_estimate(self) -> tuple[np.ndarray, np.ndarray]:
        """(x0_est (2N,), P0 (2N, 2N))."""
        x = np.zeros(len(self.x0)) if self.x0_est is None else np.array(self.x0_est, dtype=np.float64)
        return x, np.diag(np.array(self.p0_diag, dtype=np.float64))

    def truth(self) -> np.ndarray:
        """(steps + 1, 2N): constant-velocity truth at every t_k (paper 003 eq. (1), Q = 0)."""
        n, x0 = self.n_targets, np.array(self.x0, dtype=np.float64)
        pos = x0[:n] + self.times[:, None] * x0[n:]
        return np.concatenate([pos, np.broadcast_to(x0[n:], pos.shape)], axis=1)

    def crossing_times(self) -> tuple[tuple[int, int, float], ...]:
        """(i, j, t) for every pair of targets (0-based) that meet at a time 0 < t <= steps dt, by time."""
        n, x0 = self.n_targets, self.x0
        out = []
        for i in range(n):
            for j in range(i + 1, n):
                dv = x0[n + i] - x0[n + j]
                if dv != 0.0:
                    t = -(x0[i] - x0[j]) / dv
                    if 0.0 < t <= self.steps * self.dt:
                        out.append((i, j, t))
        return tuple(sorted(out, key=lambda c: c[2]))


def paper_scenario(n_targets: int = 3, steps: int = 2000) -> LineTargets:
    """The paper's set-up (module docstring) for N = 3, or its first two targets for N = 2."""
    if n_targets == 3:
        return LineTargets(x0=PAPER_X0, p0_diag=PAPER_P0_DIAG, steps=steps)
    if n_targets == 2:
        return LineTargets(x0=(3.0, 25.0, 10.0, 5.0), p0_diag=(9.0, 625.0, 100.0, 25.0), steps=steps)
    raise ValueError(f"paper_scenario has N = 2 or 3 targets, got {n_targets!r}")


@dataclass(frozen=True)
class LineRuns:
    """truth (steps + 1, 2N) shared by every run; z (R, steps, N) labelled noisy positions of scans 1..steps."""

    truth: np.ndarray
    z: np.ndarray
    sigma: float

    def symmetric(self, form: str) -> np.ndarray:
        """y (R, steps, N): what the symmetric sensor of `form` reports from the same noisy positions."""
        return SymmetricSensor(form, self.z.shape[-1], self.sigma).transform(self.z)


def simulate(scn: LineTargets, n_runs: int, seed: int) -> LineRuns:
    """n_runs seeded runs of scenario `scn` (streams in the module docstring)."""
    truth = scn.truth()
    pos = truth[1:, : scn.n_targets]
    streams = np.random.SeedSequence(seed).spawn(n_runs)
    z = np.stack([associated_positions(pos, scn.sigma, np.random.default_rng(s)) for s in streams])
    return LineRuns(truth=truth, z=z, sigma=scn.sigma)


# ------------------------------------------------------------------------------------------- tracking
def _initial(scn: LineTargets, n_runs: int, P0: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """(x0 (R, 2N), P0 (R, 2N, 2N)): the scenario's initial estimate, or per-run covariances P0 (R, 2N, 2N)."""
    x0, P = scn.initial_estimate
    P0 = np.broadcast_to(P, (n_runs,) + P.shape) if P0 is None else np.asarray(P0, dtype=np.float64)
    if P0.shape != (n_runs,) + P.shape:
        raise ValueError(f"P0 must have shape {(n_runs,) + P.shape}, got {P0.shape}")
    return np.broadcast_to(x0, (n_runs,) + x0.shape), P0


def track_symmetric(scn: LineTargets, runs: LineRuns, form: str, P0: np.ndarray | None = None) -> np.ndarray:
    """The SME EKF of `form` over every run at once: unlabelled estimates (R, steps + 1, 2N) from t = 0.
    P0: per-run initial covariances (R, 2N, 2N) instead of the scenario's."""
    trk = SMETracker(SymmetricMeasurement(form, scn.n_targets, scn.sigma))
    y = runs.symmetric(form)
    n_runs = y.shape[0]
    x0, P0 = _initial(scn, n_runs, P0)
    s = trk.initial_state(x0, P0)
    out = np.empty((n_runs, scn.steps + 1, x0.shape[-1]))
    out[:, 0] = s.x
    for k in range(scn.steps):
        s = trk.update(trk.predict(s, scn.dt), y[:, k])
        out[:, k + 1] = s.x
    return out


def track_associated(scn: LineTargets, runs: LineRuns, P0: np.ndarray | None = None) -> np.ndarray:
    """The linear KF on the labelled positions z (paper 003 eq. (2), Kamen's "associated filter"), the core's
    KalmanFilter with the runs as a batch of tracks: estimates (R, steps + 1, 2N), labelled by construction.
    P0 as in `track_symmetric`."""
    n = scn.n_targets
    kf = KalmanFilter(ConstantVelocity(sigma_v=0.0, dims=n), PositionMeasurement(scn.sigma, dims=n))
    n_runs = runs.z.shape[0]
    x0, P0 = _initial(scn, n_runs, P0)
    states = [kf.initial_state(x0[r], P0[r]) for r in range(n_runs)]
    out = np.empty((n_runs, scn.steps + 1, x0.shape[-1]))
    out[:, 0] = x0
    W, w0 = np.ones((n_runs, 1)), np.zeros(n_runs)
    for k in range(scn.steps):
        pred = kf.predict_many(states, scn.dt)
        z_hat = np.array([p.x[:n] for p in pred])
        states = kf.update_many(pred, (runs.z[:, k] - z_hat)[:, None, :], W, w0)
        out[:, k + 1] = [s.x for s in states]
    return out


# -------------------------------------------------------------------------------------------- scoring
def labelled(est: np.ndarray, truth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(estimates relabelled at every step (R, K + 1, 2N), permutations (R, K + 1, N)): slot perm[i] is named
    target i by the minimum squared error against truth (K + 1, 2N) (paper 003 §IV; per step [D])."""
    perm = label_permutation(est, np.broadcast_to(truth, est.shape))
    return relabel(est, perm), perm


def position_rmse(est: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """RMSE over runs of each target's position (K + 1, N) [m] for labelled estimates (R, K + 1, 2N)."""
    n = truth.shape[-1] // 2
    return np.sqrt(((est[..., :n] - truth[None, :, :n]) ** 2).mean(axis=0))


def diverged(est: np.ndarray, truth: np.ndarray, threshold: float) -> np.ndarray:
    """(R,) bool: a labelled final position error above `threshold` [m] for some target."""
    n = truth.shape[-1] // 2
    return np.abs(est[:, -1, :n] - truth[-1, :n]).max(axis=-1) > threshold


def label_exchanges(perm: np.ndarray, first_step: int) -> np.ndarray:
    """(R,) number of steps from `first_step` on at which the labelling permutation changes (track exchanges)."""
    p = perm[:, first_step:]
    return (p[:, 1:] != p[:, :-1]).any(axis=-1).sum(axis=-1)
