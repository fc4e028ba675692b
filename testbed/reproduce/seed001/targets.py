"""Paper 001's abstract scenarios (§5) and a per-target tracking loop with PDA or all-neighbours (AN) weights.

Point targets move in the plane with state [x, y, vx, vy] (m, m/s), X(k+1) = F X(k) + G a(k) (paper 001 (1)-(3));
a sensor sees every target every scan with noise N(0, sigma^2 I) (4)-(7) and adds Poisson(b) clutter points
per scan (8), uniform over the surveillance region: the bounding box of the noise-free trajectories plus a margin
(1 km) [D]. Each track is filtered on its own (no joint events; an observation may fall in several gates).

API
    Scenario(name, x0, dt, steps, sigma, clutter_b=0.01, sigma_a_truth=0.0, margin=1000.0)
        x0: T initial states; .truth_nominal() (K+1, T, 4) straight lines; .region() (xmin, xmax, ymin, ymax) [m]
    single_target(steps=1000), crossing(), parallel()   the paper's 5.1, 5.2, 5.3 (printed parameters)
    side_by_side(separation, ...)                       two parallel targets abreast, `separation` [m] apart (ours)
    crossing_at(d_min, t_min=50.0, ...)                 5.2's velocities, closest approach d_min [m] at t_min (ours)
    simulate(scn, n_runs, seed) -> Runs                 truth (R, K+1, T, 4), Z (R, K, M, 2), origin (R, K, M)
    stack(runs_list) -> Runs                            several scenarios' runs (same K, T) as one batch
    Method(weights, covariance, distance, n_mode); METHODS: "pda", "an" (paper (22)-(25)), "an-spread"
    Filter(sigma_a=0.5, gate=4.0, p0_diag=None)         settings shared by every method
    track(runs, dt, sigma, method, flt) -> Tracks       all runs and targets at once, from the true X(0)
    reference_sigma(dt, steps, sigma, flt) -> (K+1,)    clutter-free KF position std (largest eigenvalue) [m]
    lost_by_error(err, tau, min_steps=5), lost_by_gate(own_gated, min_steps=5) -> (R, T) bool

Update (paper 001 (13)-(15), (20)-(21), (25)): K = P H^T S^-1, x = x + K sum_j P_ij e_ij, and
    covariance "kf"     P = w0 P- + (1 - w0) (I - K H) P-                    paper (25) (w0 = 1: coast)
    covariance "spread" P = w0 P- + (1 - w0) (I - K H) P- + K dP K^T         PDA (20)-(21), Bar-Shalom's w0 form
with dP = sum_j P_ij e_ij e_ij^T - e e^T. The project's "an-kf" tracker (trackers.filters.kalman.gain_update)
is the "an-spread" form (its Joseph-form P* equals (I - K H) P- for the optimal gain).

Random streams: per run `SeedSequence(seed).spawn(n_runs)[r].spawn(3)` -> truth acceleration, measurement noise,
clutter; each is drawn whatever the scenario's separation or clutter rate, so the runs of a sweep share their
noise (common random numbers). Time: scan k is at t = k dt [s].
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from roadtrack.testbed.reproduce.thesis.synthetic import lost_at
from roadtrack.trackers.association.an import DISTANCES, all_neighbours, an_distances
from roadtrack.trackers.association.params import AssociationParams
from roadtrack.trackers.association.pda import pda
from roadtrack.trackers.models import ConstantVelocity

N_MODES = ("gated", "scan")
COVARIANCES = ("kf", "spread")
WEIGHTS = ("pda", "an")


# ------------------------------------------------------------------------------------------ scenarios
@dataclass(frozen=True)
class Scenario:
    """x0: T initial states [x, y, vx, vy] (m, m/s); dt [s]; steps K; sigma [m] measurement std per axis;
    clutter_b: mean clutter points per scan over the region (paper (8)); sigma_a_truth [m/s^2]: white
    acceleration of the truth (0: the straight lines of the paper's §5 [I]); margin [m] around the trajectories."""

    name: str
    x0: tuple[tuple[float, float, float, float], ...]
    dt: float
    steps: int
    sigma: float
    clutter_b: float = 0.01
    sigma_a_truth: float = 0.0
    margin: float = 1000.0

    def __post_init__(self) -> None:
        x0 = np.asarray(self.x0, dtype=np.float64)
        if x0.ndim != 2 or x0.shape[1] != 4 or x0.shape[0] < 1 or not np.isfinite(x0).all():
            raise ValueError(f"Scenario.x0 must be T >= 1 finite states of 4 numbers, got {self.x0!r}")
        if not (isinstance(self.steps, int) and self.steps >= 1):
            raise ValueError(f"Scenario.steps must be an int >= 1, got {self.steps!r}")
        if not (self.dt > 0 and self.sigma > 0 and self.clutter_b >= 0 and self.sigma_a_truth >= 0
                and self.margin >= 0):
            raise ValueError("Scenario needs dt > 0, sigma > 0, clutter_b >= 0, sigma_a_truth >= 0, margin >= 0")

    @property
    def n_targets(self) -> int:
        return len(self.x0)

    @property
    def times(self) -> np.ndarray:
        """(K+1,) scan times [s]."""
        return np.arange(self.steps + 1) * self.dt

    def truth_nominal(self) -> np.ndarray:
        """(K+1, T, 4) noise-free constant-velocity trajectories."""
        x0 = np.asarray(self.x0, dtype=np.float64)
        X = np.repeat(x0[None], self.steps + 1, axis=0)
        X[:, :, :2] += self.times[:, None, None] * x0[None, :, 2:]
        return X

    def region(self) -> np.ndarray:
        """(xmin, xmax, ymin, ymax) [m]: the noise-free trajectories' bounding box plus `margin` [D]."""
        p = self.truth_nominal()[..., :2].reshape(-1, 2)
        lo, hi = p.min(axis=0) - self.margin, p.max(axis=0) + self.margin
        return np.array([lo[0], hi[0], lo[1], hi[1]])

    def area(self) -> float:
        r = self.region()
        return float((r[1] - r[0]) * (r[3] - r[2]))


def single_target(steps: int = 1000, **kw) -> Scenario:
    """Paper 001 §5.1: X(0) = [6000, 6000, 150, 60], T = 0.1 s, 1000 samples, sigma = 30 m, b = 0.01 [T]."""
    return Scenario("5.1 single target", ((6000.0, 6000.0, 150.0, 60.0),), 0.1, steps, 30.0, **kw)


def crossing(**kw) -> Scenario:
    """Paper 001 §5.2: X1(0) = [7000, 7000, 130, 40] [R] (the printed, garbled "17000" read as 7000); X1's other
    entries, X2(0) = [7000, 8000, 110, 0], T = 1 s, 100 samples, sigma = 50 m, b = 0.01 as printed [T]. Closest
    approach 447 m at t = 20 s [I]."""
    return Scenario("5.2 crossing", ((7000.0, 7000.0, 130.0, 40.0), (7000.0, 8000.0, 110.0, 0.0)), 1.0, 100, 50.0,
                    **kw)


def parallel(**kw) -> Scenario:
    """Paper 001 §5.3: X1(0) = [6000, 6000, 150, 60], X2(0) = [7000, 7000, 150, 60], T = 1 s, 100 samples,
    sigma = 50 m, b = 0.01 [T]. Constant separation 1414 m (557 m across the track) [I]."""
    return Scenario("5.3 parallel", ((6000.0, 6000.0, 150.0, 60.0), (7000.0, 7000.0, 150.0, 60.0)), 1.0, 100, 50.0,
                    **kw)


def side_by_side(separation: float, steps: int = 100, **kw) -> Scenario:
    """Two targets abreast with 5.3's velocity (150, 60) m/s: target 2 is target 1 (5.3's) moved `separation` [m]
    across the track (along-track offset 0) [D: the sweep's geometry]."""
    if not (math.isfinite(separation) and separation >= 0):
        raise ValueError(f"separation must be finite and >= 0, got {separation!r}")
    v = np.array([150.0, 60.0])
    n = np.array([-v[1], v[0]]) / np.hypot(*v)  # unit normal to the track
    p2 = np.array([6000.0, 6000.0]) + separation * n
    return Scenario(f"parallel abreast {separation:g} m", ((6000.0, 6000.0, 150.0, 60.0), (*p2, 150.0, 60.0)),
                    1.0, steps, 50.0, **kw)


def crossing_at(d_min: float, t_min: float = 50.0, steps: int = 100, **kw) -> Scenario:
    """5.2's targets (velocities (130, 40) and (110, 0) m/s, target 1 from [7000, 7000]) with target 2 placed so
    that the closest approach is `d_min` [m] at `t_min` [s], on the side of 5.2's geometry. crossing_at(447.21, 20)
    is the paper's 5.2 [I]."""
    if not (math.isfinite(d_min) and d_min >= 0 and 0 <= t_min <= steps):
        raise ValueError(f"crossing_at needs finite d_min >= 0 and 0 <= t_min <= steps, got {d_min!r}, {t_min!r}")
    v1, v2 = np.array([130.0, 40.0]), np.array([110.0, 0.0])
    rel = v1 - v2
    n = np.array([-rel[1], rel[0]]) / np.hypot(*rel)  # unit normal to the relative velocity
    p2 = np.array([7000.0, 7000.0]) + t_min * v1 + d_min * n - t_min * v2
    return Scenario(f"crossing d_min {d_min:g} m", ((7000.0, 7000.0, 130.0, 40.0), (*p2, 110.0, 0.0)), 1.0, steps,
                    50.0, **kw)


# ------------------------------------------------------------------------------------------ simulation
@dataclass(frozen=True, eq=False)
class Runs:
    """truth (R, K+1, T, 4) [m, m/s]; Z (R, K, M, 2) measurements of scans 1..K [m], NaN-padded; origin (R, K, M)
    int64: t for target t's detection, -1 clutter, -2 padding (scoring only, trackers never read it);
    density (R,) clutter density lambda = b / area [1/m^2]."""

    truth: np.ndarray
    Z: np.ndarray
    origin: np.ndarray
    density: np.ndarray

    @property
    def n_runs(self) -> int:
        return self.truth.shape[0]


def _truth(scn: Scenario, accel: np.ndarray) -> np.ndarray:
    """(K+1, T, 4) from X(0) and the accelerations a(k) (K, T, 2): X(k+1) = F X(k) + G a(k), paper 001 (1)-(3)."""
    dt = scn.dt
    x0 = np.asarray(scn.x0, dtype=np.float64)
    v = x0[None, :, 2:] + dt * np.concatenate([np.zeros_like(accel[:1]), np.cumsum(accel, axis=0)])  # v(k)
    step = dt * v[:-1] + 0.5 * dt * dt * accel  # p(k+1) - p(k)
    p = x0[None, :, :2] + np.concatenate([np.zeros_like(accel[:1]), np.cumsum(step, axis=0)])
    return np.concatenate([p, v], axis=-1)


def simulate(scn: Scenario, n_runs: int, seed: int | np.random.SeedSequence) -> Runs:
    """`n_runs` seeded runs of `scn` (see the module docstring for the random streams)."""
    if not (isinstance(n_runs, int) and n_runs >= 1):
        raise ValueError(f"n_runs must be an int >= 1, got {n_runs!r}")
    ss = seed if isinstance(seed, np.random.SeedSequence) else np.random.SeedSequence(seed)
    K, T = scn.steps, scn.n_targets
    reg = scn.region()
    truths, dets, clutters = [], [], []
    for run_ss in ss.spawn(n_runs):
        g_truth, g_noise, g_clutter = (np.random.default_rng(s) for s in run_ss.spawn(3))
        X = _truth(scn, g_truth.normal(size=(K, T, 2)) * scn.sigma_a_truth)
        truths.append(X)
        dets.append(X[1:, :, :2] + g_noise.normal(size=(K, T, 2)) * scn.sigma)  # paper 001 (4): Z = H X + V
        counts = g_clutter.poisson(scn.clutter_b, size=K)  # paper 001 (8): Poisson(b) clutter points per scan
        u = g_clutter.random(size=(int(counts.sum()), 2))
        pts = np.column_stack([reg[0] + u[:, 0] * (reg[1] - reg[0]), reg[2] + u[:, 1] * (reg[3] - reg[2])])
        clutters.append((counts, pts))
    M = T + max(int(c.max()) for c, _ in clutters)
    Z = np.full((n_runs, K, M, 2), np.nan)
    origin = np.full((n_runs, K, M), -2, dtype=np.int64)
    for r, (det, (counts, pts)) in enumerate(zip(dets, clutters)):
        Z[r, :, :T] = det
        origin[r, :, :T] = np.arange(T)
        k_of = np.repeat(np.arange(K), counts)
        slot = T + np.arange(len(k_of)) - np.repeat(np.cumsum(counts) - counts, counts)
        Z[r, k_of, slot] = pts
        origin[r, k_of, slot] = -1
    return Runs(truth=np.stack(truths), Z=Z, origin=origin, density=np.full(n_runs, scn.clutter_b / scn.area()))


def stack(runs: list[Runs]) -> Runs:
    """One batch from several Runs of equal K and T (measurement slots padded to the largest M)."""
    if not runs or len({(r.truth.shape[1], r.truth.shape[2]) for r in runs}) != 1:
        raise ValueError("stack needs a non-empty list of Runs with the same number of scans and targets")
    M = max(r.Z.shape[2] for r in runs)

    def pad(a: np.ndarray, fill) -> np.ndarray:
        width = [(0, 0)] * a.ndim
        width[2] = (0, M - a.shape[2])
        return np.pad(a, width, constant_values=fill)

    return Runs(truth=np.concatenate([r.truth for r in runs]), Z=np.concatenate([pad(r.Z, np.nan) for r in runs]),
                origin=np.concatenate([pad(r.origin, -2) for r in runs]),
                density=np.concatenate([r.density for r in runs]))


# ------------------------------------------------------------------------------------------ tracking
@dataclass(frozen=True)
class Method:
    """weights: "pda" (normalised Gaussian likelihoods with P_D = P_G = 1, paper 001 §3 [R]) or "an" (22)-(23);
    covariance: "kf" ((25), no spread) or "spread" ((20)-(21)); distance: D_ij of (23) for AN (Euclidean [D],
    Mahalanobis or its square); n_mode: AN's N = observations in the track's gate [D] or the whole scan's."""

    weights: str
    covariance: str
    distance: str = "euclidean"
    n_mode: str = "gated"

    def __post_init__(self) -> None:
        if self.weights not in WEIGHTS or self.covariance not in COVARIANCES:
            raise ValueError(f"Method needs weights in {list(WEIGHTS)} and covariance in {list(COVARIANCES)}, got "
                             f"{self.weights!r}, {self.covariance!r}")
        if self.distance not in DISTANCES or self.n_mode not in N_MODES:
            raise ValueError(f"Method needs distance in {list(DISTANCES)} and n_mode in {list(N_MODES)}, got "
                             f"{self.distance!r}, {self.n_mode!r}")


METHODS: dict[str, Method] = {
    "pda": Method("pda", "spread"),  # paper 001 §3: PDA weights, covariance (20)-(21)
    "an": Method("an", "kf"),  # paper 001 §4: weights (22)-(23), covariance (25)
    "an-spread": Method("an", "spread"),  # (22)-(23) with PDA's (20)-(21): the project's "an-kf"
}


@dataclass(frozen=True)
class Filter:
    """sigma_a [m/s^2] the filters' white acceleration (Q = sigma_a^2 I, paper (1)-(3); value lost, 0.5 [D]);
    gate g (9): e^T S^-1 e <= g^2 (4 [D]); p0_diag: P0 diagonal (m^2, m^2, m^2/s^2, m^2/s^2), None:
    (sigma^2, sigma^2, 100, 100) [D]."""

    sigma_a: float = 0.5
    gate: float = 4.0
    p0_diag: tuple[float, float, float, float] | None = None

    def __post_init__(self) -> None:
        if not (self.sigma_a >= 0 and self.gate > 0):
            raise ValueError(f"Filter needs sigma_a >= 0 and gate > 0, got {self.sigma_a!r}, {self.gate!r}")
        if self.p0_diag is not None and (len(self.p0_diag) != 4 or min(self.p0_diag) <= 0):
            raise ValueError(f"Filter.p0_diag must be 4 positive variances, got {self.p0_diag!r}")

    def p0(self, sigma: float) -> np.ndarray:
        return np.diag(self.p0_diag if self.p0_diag is not None else (sigma ** 2, sigma ** 2, 100.0, 100.0))


@dataclass(frozen=True, eq=False)
class Tracks:
    """x (R, K+1, T, 4) estimates X(k|k) (index 0: the true X(0), "perfectly known"); n_gated (R, K, T);
    own_gated (R, K, T) bool: the track's own target's detection is in its gate; w_own, w_other (R, K, T): the
    weight on the own target's detection and on the other targets' detections; sqrt_s (R, K, T) [m]:
    sqrt(mean diag S), the per-axis innovation std (gate radius = g sqrt_s)."""

    x: np.ndarray
    n_gated: np.ndarray
    own_gated: np.ndarray
    w_own: np.ndarray
    w_other: np.ndarray
    sqrt_s: np.ndarray

    def position_error(self, truth: np.ndarray) -> np.ndarray:
        """(R, K+1, T) Euclidean position error [m] against truth (R, K+1, T, 4)."""
        d = self.x[..., :2] - truth[..., :2]
        return np.hypot(d[..., 0], d[..., 1])


def _weights(method: Method, nu: np.ndarray, d2: np.ndarray, log_det: np.ndarray, gated: np.ndarray,
             valid: np.ndarray, density: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(W (R, T, M), w0 (R, T)) from innovations nu (R, T, M, 2), d2 (R, T, M), log|S| (R, T), gates (R, T, M)."""
    R, T, M = d2.shape
    if method.weights == "an":
        D = an_distances(nu.reshape(R * T, M, 2), d2.reshape(R * T, M), method.distance)  # paper 001 (23)
        mask = gated if method.n_mode == "gated" else np.broadcast_to(valid[:, None, :], gated.shape)
        W, w0 = all_neighbours(D, mask.reshape(R * T, M))  # paper 001 (22)
        return W.reshape(R, T, M), w0.reshape(R, T)
    log_lik = -0.5 * d2 - math.log(2.0 * math.pi) - 0.5 * log_det[..., None]  # log N(e; 0, S), M = 2
    W, w0 = np.zeros((R, T, M)), np.ones((R, T))
    for lam in np.unique(density):
        rows = density == lam
        # paper 001 §3: P_G = 1 [T], P_D = 1 [D]; then b_PDA = 0 and lambda cancels out of the weights, so a
        # clutter-free scene (lambda = 0, which AssociationParams refuses) may pass any positive value
        p = AssociationParams(pd=1.0, pg=1.0, clutter_density=float(lam) if lam > 0 else 1.0)
        w, b0 = pda(log_lik[rows].reshape(-1, M), gated[rows].reshape(-1, M), p)  # (16)-(19) [R]: Bar-Shalom & Tse
        W[rows], w0[rows] = w.reshape(-1, T, M), b0.reshape(-1, T)
    return W, w0


def track(runs: Runs, dt: float, sigma: float, method: Method, flt: Filter = Filter()) -> Tracks:
    """Every track of every run filtered on its own from the true X(0) with P0 (no track management): predict
    (24) -> gate (9)-(11) -> weights -> update (13)-(15) with the method's covariance (module docstring)."""
    R, K1, T, _ = runs.truth.shape
    K, M = K1 - 1, runs.Z.shape[2]
    cv = ConstantVelocity(flt.sigma_a)
    F, Q = cv.transition(dt), cv.process_noise(dt)  # paper 001 (1)-(3), Q = G sigma_a^2 I G^T
    Rm = sigma ** 2 * np.eye(2)  # paper 001 (7)
    x = runs.truth[:, 0].copy()  # "perfectly known" initial states [T]
    P = np.broadcast_to(flt.p0(sigma), (R, T, 4, 4)).copy()
    xs = np.zeros((R, K1, T, 4))
    xs[:, 0] = x
    n_gated, own_gated = np.zeros((R, K, T), dtype=np.int64), np.zeros((R, K, T), dtype=bool)
    w_own, w_other, sqrt_s = np.zeros((R, K, T)), np.zeros((R, K, T)), np.zeros((R, K, T))
    own = runs.origin[:, :, None, :] == np.arange(T)[None, None, :, None]  # (R, K, T, M)
    other = (runs.origin[:, :, None, :] >= 0) & ~own
    g2 = flt.gate ** 2
    for k in range(K):
        x = x @ F.T  # paper 001 (24): X(k|k-1) = F X(k-1|k-1)
        P = F @ P @ F.T + Q  # (24): P(k|k-1) = F P F^T + G Q G^T
        valid = runs.origin[:, k] >= -1  # (R, M)
        nu = np.where(valid[:, None, :, None], np.nan_to_num(runs.Z[:, k])[:, None] - x[:, :, None, :2], 0.0)  # (10)
        S = P[..., :2, :2] + Rm  # (11): S = H P H^T + R
        S_inv = np.linalg.inv(S)
        d2 = np.einsum("rtmi,rtij,rtmj->rtm", nu, S_inv, nu)
        gated = valid[:, None, :] & (d2 <= g2)  # (9): e^T S^-1 e <= g^2
        W, w0 = _weights(method, nu, d2, np.linalg.slogdet(S)[1], gated, valid, runs.density)
        gain = P[..., :, :2] @ S_inv  # (14): K = P H^T S^-1, (R, T, 4, 2)
        e = np.einsum("rtm,rtmi->rti", W, nu)  # (15): combined innovation
        x = x + np.einsum("rtij,rtj->rti", gain, e)  # (13)
        P_kf = P - gain @ P[..., :2, :]  # (25): (I - K H) P(k|k-1)
        Pn = w0[..., None, None] * P + (1.0 - w0)[..., None, None] * P_kf  # w0 = 1 (nothing gated): coast
        if method.covariance == "spread":
            spread = np.einsum("rtm,rtmi,rtmj->rtij", W, nu, nu) - e[..., :, None] * e[..., None, :]
            Pn = Pn + gain @ spread @ np.swapaxes(gain, -1, -2)  # (20)-(21): + K dP K^T
        P = 0.5 * (Pn + np.swapaxes(Pn, -1, -2))
        xs[:, k + 1] = x
        n_gated[:, k] = gated.sum(axis=-1)
        own_gated[:, k] = (gated & own[:, k]).any(axis=-1)
        w_own[:, k] = (W * own[:, k]).sum(axis=-1)
        w_other[:, k] = (W * other[:, k]).sum(axis=-1)
        sqrt_s[:, k] = np.sqrt(0.5 * (S[..., 0, 0] + S[..., 1, 1]))
    return Tracks(x=xs, n_gated=n_gated, own_gated=own_gated, w_own=w_own, w_other=w_other, sqrt_s=sqrt_s)


def reference_sigma(dt: float, steps: int, sigma: float, flt: Filter = Filter()) -> np.ndarray:
    """(K+1,) sqrt of the largest eigenvalue of the position block of P(k|k) of a clutter-free KF that updates
    every scan with its own detection: the correct-association position std [m], the same for every method."""
    cv = ConstantVelocity(flt.sigma_a)
    F, Q = cv.transition(dt), cv.process_noise(dt)
    P = flt.p0(sigma)
    out = np.zeros(steps + 1)
    out[0] = math.sqrt(np.linalg.eigvalsh(P[:2, :2])[-1])
    for k in range(steps):
        P = F @ P @ F.T + Q  # (24)
        gain = P[:, :2] @ np.linalg.inv(P[:2, :2] + sigma ** 2 * np.eye(2))  # (14)
        P = P - gain @ P[:2, :]  # (25)
        P = 0.5 * (P + P.T)
        out[k + 1] = math.sqrt(np.linalg.eigvalsh(P[:2, :2])[-1])
    return out


# ------------------------------------------------------------------------------------------ track loss
def lost_by_error(err: np.ndarray, tau: np.ndarray, min_steps: int = 5) -> np.ndarray:
    """(R, T) bool: the position error err (R, K+1, T) [m] exceeds tau (K+1,) [m] at every scan of a tail of at
    least `min_steps` scans ending at the last scan (synthetic.lost_at)."""
    ratio = np.asarray(err) / np.asarray(tau)[None, :, None]
    R, _, T = ratio.shape
    return np.array([[lost_at(ratio[r, :, t], 1.0, min_steps) is not None for t in range(T)] for r in range(R)])


def lost_by_gate(own_gated: np.ndarray, min_steps: int = 5) -> np.ndarray:
    """(R, T) bool: the track's own target's detection was outside its gate at each of the last `min_steps` or
    more scans (own_gated (R, K, T) bool)."""
    miss = 1.0 - np.asarray(own_gated, dtype=np.float64)
    R, _, T = miss.shape
    return np.array([[lost_at(miss[r, :, t], 0.5, min_steps) is not None for t in range(T)] for r in range(R)])
