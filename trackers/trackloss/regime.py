"""Track regime detector (TRD) of paper 002 (Powers & Pao): is a track 'tracking' or 'track-lost', without truth?

Over the last n scans the number of measurements in two re-drawn gates is compared, by two-sided KS tests, with
the count distributions of the two regimes: tracking (the target's own measurement, Bernoulli P_D P_G, plus
Poisson clutter) and track-lost (Poisson clutter only). The gates use gamma_best, the gate size that maximises the
largest gap Delta_F between the two cdfs (the asymptotic power), and the mean gate volume V_c of the window:
    NG (non-constant volume, tests 'tracking'):   nu' S(j)^-1 nu <= gamma_best                    (10)
    CG (constant volume V_c, tests 'track-lost'): nu' s_j S(j)^-1 nu <= gamma_best, s_j = (V_j / V_c)^(2/n_z)  (9)
Verdicts (§V): tracking (H_T accepted, H_L rejected), track-lost (the reverse), both (n too small), neither (a
possible loss, or model error); `label` folds both and neither into 'ambiguous'. The adaptive rule (§V-F)
grows n while both regimes are accepted, shrinks it while neither is, and raises the CI when that fails.

Inputs for a window of n scans j = 0..n-1 (oldest first): root_det (n,) = |S(j)|^(1/2) [m^n_z]; d2_scans, n
arrays: the squared Mahalanobis distances nu' S(j)^-1 nu of EVERY measurement of each scan (not only the gated
ones: the CG gate can be larger than the tracker's gate); pd (n,) P_D per scan; lam the clutter density
[1/m^n_z]. `window_from_history` reads them from a trackers.tracker Track.history (any filter, any associator);
`regime_series` runs the detector scan by scan over a recorded series. A tracker does not rebuild the windows
from the histories every scan: it rolls each track's window in its RegimeState (`window_rows`, `roll_windows`:
per scan |S|^(1/2), P_D, M and the WINDOW_LOW smallest distances) and tests them with `assess_rolled`, which gives
assess_windows' tests bit for bit (a count that reaches WINDOW_LOW is recounted on the record's full d2).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field, replace
from typing import Callable, Sequence

import numpy as np
from scipy.special import gammainc, gammaln, pdtr, xlogy

from roadtrack.trackers.trackloss.ks import critical_value, ks_distance_counts, ks_distances_counts

VERDICTS = ("tracking", "track-lost", "both", "neither")
LABELS = ("unknown", "tracking", "track-lost", "ambiguous")
GAMMA_RANGE = (0.01, 50.0)  # [D] bounded search for gamma_best (reference: [0.01, 50])


# ------------------------------------------------------------------------------------------ regime cdfs
def unit_ball_volume(nz: int) -> float:
    """c_nz = pi^(nz/2) / Gamma(nz/2 + 1) (c_1 = 2, c_2 = pi, c_3 = 4 pi / 3)."""
    return math.exp(0.5 * nz * math.log(math.pi) - float(gammaln(0.5 * nz + 1.0)))  # paper 002 (1)


def gate_probability(gamma, nz: int):
    """P_G(gamma) = F_chi2_nz(gamma), vectorised over gamma."""
    return gammainc(0.5 * nz, 0.5 * np.asarray(gamma, dtype=np.float64))  # paper 002 §II-C P_G


def poisson_pmf(m, mu):
    """Pois(m; mu) = mu^m e^-mu / Gamma(m + 1) for real m >= 0 (mu = 0 gives 1 at m = 0)."""
    m, mu = np.asarray(m, dtype=np.float64), np.asarray(mu, dtype=np.float64)
    return np.exp(xlogy(m, mu) - mu - gammaln(m + 1.0))


def lost_cdf(m, mu):
    """F_L(m) = sum_{i<=m} Pois(i; mu), mu = lambda V (clutter only)."""
    return pdtr(np.asarray(m), np.asarray(mu, dtype=np.float64))  # paper 002 (2)


def tracking_cdf(m, mu, pdpg):
    """F_T(m): clutter Pois(mu) plus the target's measurement with probability P_D P_G (as printed)."""
    m = np.asarray(m)
    below = pdtr(np.maximum(m - 1, 0), mu)
    head = np.where(m >= 1, below, 0.0)  # paper 002 (3): sum_{i<m} Pois(i) for m >= 1, nothing for m = 0
    return head + (1.0 - np.asarray(pdpg)) * poisson_pmf(m, mu)  # paper 002 (3)


def _tracking_from_lost(F_L, m, mu, pdpg):
    """tracking_cdf(m, mu, pdpg) (T, M) at m = 0..M-1 (m (1, M)) from F_L = lost_cdf(m, mu) (T, M): its head
    sum_{i<m} Pois(i) is F_L one count back (the same pdtr values), so one pdtr call serves both regimes."""
    head = np.zeros_like(F_L)
    head[:, 1:] = F_L[:, :-1]  # paper 002 (3): sum_{i<m} Pois(i) for m >= 1, nothing for m = 0
    return head + (1.0 - np.asarray(pdpg)) * poisson_pmf(m, mu)  # paper 002 (3)


def cdf_gap(m, mu, pdpg):
    """Delta_F(m) = F_L(m) - F_T(m) = P_D P_G Pois(m; mu) >= 0, for real m as well."""
    return np.asarray(pdpg) * poisson_pmf(m, mu)  # paper 002 (11)-(12)


# ------------------------------------------------------------------------------------------ gamma_best
def delta_f(gamma, lam_sigma, nz: int, pd=1.0):
    """Delta_F(lambda V_c, gamma) = P_D P_G(gamma) phi(lambda V_c), phi(a) = a^a e^-a / Gamma(a + 1), with
    V_c = c_nz gamma^(nz/2) Sigma_n; broadcast over gamma and lam_sigma = lambda Sigma_n."""
    gamma = np.asarray(gamma, dtype=np.float64)
    a = np.asarray(lam_sigma, dtype=np.float64) * unit_ball_volume(nz) * gamma ** (0.5 * nz)  # paper 002 (8)
    return np.asarray(pd) * gate_probability(gamma, nz) * poisson_pmf(a, a)  # paper 002 §V-D Delta_F(lam V_c)


def gamma_best(lam_sigma, nz: int, bounds: tuple[float, float] = GAMMA_RANGE, iterations: int = 40):
    """argmax_gamma Delta_F(lambda V_c, gamma) (paper 002 §V-D, one maximum) by golden section in log gamma,
    vectorised over lam_sigma (P_D only scales Delta_F). 40 iterations: relative error < 1e-7 in gamma."""
    x = np.asarray(lam_sigma, dtype=np.float64)
    lo, hi = np.full(x.shape, math.log(bounds[0])), np.full(x.shape, math.log(bounds[1]))
    r = (math.sqrt(5.0) - 1.0) / 2.0

    def f(t):
        return np.log(delta_f(np.exp(t), x, nz))

    c, d = hi - r * (hi - lo), lo + r * (hi - lo)
    fc, fd = f(c), f(d)
    for _ in range(iterations):
        left = fc >= fd  # the maximum lies in [lo, d]
        hi, lo = np.where(left, d, hi), np.where(left, lo, c)
        probe = np.where(left, hi - r * (hi - lo), lo + r * (hi - lo))  # the one new interior point
        f_new = f(probe)
        c, d = np.where(left, probe, d), np.where(left, c, probe)
        fc, fd = np.where(left, f_new, fd), np.where(left, fc, f_new)
    out = np.exp(0.5 * (lo + hi))
    return float(out) if out.ndim == 0 else out


_TABLE_LOG_X = (-20.0, 8.0, 1121)  # log(lambda Sigma_n) grid of the gamma_best table: 0.025 apart


@functools.lru_cache(maxsize=8)
def _gamma_table(nz: int) -> tuple[np.ndarray, np.ndarray]:
    t = np.linspace(*_TABLE_LOG_X)
    g = gamma_best(np.exp(t), nz, iterations=60)
    t.setflags(write=False)
    g = np.log(g)
    g.setflags(write=False)
    return t, g


def gamma_best_fast(lam_sigma, nz: int):
    """gamma_best from a cached table (log-log interpolation; 1121 points over lambda Sigma_n in [2e-9, 3e3],
    exact golden section outside): Delta_F within 1e-6 of the optimum, about 20 us for a batch of tracks."""
    x = np.asarray(lam_sigma, dtype=np.float64)
    t_grid, g_grid = _gamma_table(nz)
    with np.errstate(divide="ignore"):
        t = np.log(x)
    out = np.exp(np.interp(t, t_grid, g_grid))
    outside = (t < t_grid[0]) | (t > t_grid[-1])
    if outside.any():
        out = np.where(outside, gamma_best(np.where(outside, x, 1.0), nz), out)
    return float(out) if out.ndim == 0 else out


def constant_gate_scale(root_det, sigma_n: float, nz: int):
    """CG scale s_j = (V_j / V_c)^(2 / n_z) = (|S(j)|^(1/2) / Sigma_n)^(2 / n_z): the gate nu' s_j S^-1 nu <=
    gamma has volume V_c for every j. The paper's (9) prints (V_j / V_c)^2, right for n_z = 1 only [R]."""
    return (np.asarray(root_det, dtype=np.float64) / sigma_n) ** (2.0 / nz)  # paper 002 (9) [R]


def window_counts(d2_scans: Sequence[np.ndarray], thresholds: np.ndarray, presorted: bool = False) -> np.ndarray:
    """Measurements per scan (n,) int64 with d2 <= thresholds[j], for d2_scans: n arrays of distances (each sorted
    ascending if `presorted`: counted by bisection; else all at once)."""
    n = len(d2_scans)
    if presorted:
        return np.array([np.searchsorted(a, t, side="right") for a, t in zip(d2_scans, thresholds)], dtype=np.int64)
    flat, owner = _flatten(d2_scans)
    return np.bincount(owner[flat <= np.asarray(thresholds)[owner]], minlength=n).astype(np.int64)


def _flatten(d2_scans: Sequence[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    sizes = [a.size for a in d2_scans]
    flat = np.concatenate(d2_scans) if sum(sizes) else np.zeros(0)
    return flat, np.repeat(np.arange(len(d2_scans)), sizes)


# ------------------------------------------------------------------------------------------ one window
@dataclass(frozen=True, eq=False)
class RegimeTest:
    """One TRD decision over n scans: the two KS distances D_T (NG counts vs F_T) and D_L (CG counts vs F_L),
    the critical value d_n(alpha), the gate gamma_best, Sigma_n (mean |S|^(1/2)), V_c, lam, the mean P_D, and
    the NG and CG counts (n,) int64."""

    n: int
    alpha: float
    d_n: float
    D_T: float
    D_L: float
    gamma: float
    sigma_n: float
    volume: float
    lam: float
    pd: float
    counts_ng: np.ndarray
    counts_cg: np.ndarray

    @property
    def accept_tracking(self) -> bool:
        return self.D_T < self.d_n  # paper 002 (5): reject H_0 when D_n >= d_n(alpha)

    @property
    def accept_lost(self) -> bool:
        return self.D_L < self.d_n  # paper 002 (5)

    @property
    def verdict(self) -> str:
        """'tracking', 'track-lost', 'both' (both accepted) or 'neither' (both rejected) (paper 002 §V)."""
        t, l_ = self.accept_tracking, self.accept_lost
        return ("both" if l_ else "tracking") if t else ("track-lost" if l_ else "neither")

    @property
    def label(self) -> str:
        """'tracking', 'track-lost' or 'ambiguous' (both or neither)."""
        v = self.verdict
        return v if v in ("tracking", "track-lost") else "ambiguous"


def assess_window(root_det: np.ndarray, d2_scans: Sequence[np.ndarray], pd: np.ndarray, lam: float, nz: int,
                  alpha: float = 0.05, gamma: float | None = None, presorted: bool = False) -> RegimeTest:
    """The TRD over one window of n scans (paper 002 §V, steps 1-6): root_det (n,); d2_scans: n arrays, the
    distances of every measurement of each scan; pd (n,); gamma: the TRD gate (None: gamma_best)."""
    root_det = np.asarray(root_det, dtype=np.float64)
    n = root_det.size
    sigma_n = float(root_det.mean())  # paper 002 (8): Sigma_n = mean |S(j)|^(1/2)
    g = gamma_best_fast(lam * sigma_n, nz) if gamma is None else float(gamma)
    volume = unit_ball_volume(nz) * g ** (0.5 * nz) * sigma_n  # paper 002 (8): V_c = c gamma^(nz/2) Sigma_n
    thr_cg = g / constant_gate_scale(root_det, sigma_n, nz)  # paper 002 (9): CG gate nu' s_j S^-1 nu <= gamma
    if presorted:
        ng, cg = window_counts(d2_scans, np.full(n, g), True), window_counts(d2_scans, thr_cg, True)
    else:
        flat, owner = _flatten(d2_scans)
        ng = np.bincount(owner[flat <= g], minlength=n)  # paper 002 (10): NG gate nu' S^-1 nu <= gamma
        cg = np.bincount(owner[flat <= thr_cg[owner]], minlength=n)
    mu, pd_mean = lam * volume, float(np.mean(pd))
    pdpg = pd_mean * float(gate_probability(g, nz))  # F_T is linear in P_D: the window's mixture uses mean P_D
    m = np.arange(max(int(ng.max()), int(cg.max())) + 1)
    D_T = ks_distance_counts(ng, tracking_cdf(m, mu, pdpg))  # paper 002 §V step 4: NG counts vs F_T(V_c)
    D_L = ks_distance_counts(cg, lost_cdf(m, mu))  # paper 002 §V step 4: CG counts vs F_L(V_c)
    return RegimeTest(n=n, alpha=alpha, d_n=critical_value(n, alpha), D_T=D_T, D_L=D_L, gamma=g, sigma_n=sigma_n,
                      volume=volume, lam=lam, pd=pd_mean, counts_ng=ng, counts_cg=cg)


def assess_windows(root_det: np.ndarray, d2_scans: Sequence[Sequence[np.ndarray]], pd: np.ndarray, lam: float,
                   nz: int, alphas: np.ndarray, gammas: np.ndarray) -> list[RegimeTest]:
    """assess_window of T tracks' windows of one length n at once (a tracker's per-scan batch): root_det (T, n),
    d2_scans T sequences of n arrays, pd (T, n), alphas (T,), gammas (T,) the TRD gates. The same RegimeTests as
    T calls of assess_window(root_det[t], d2_scans[t], pd[t], lam, nz, alphas[t], gammas[t]) (tested to 1e-12)."""
    root_det, pd = np.asarray(root_det, dtype=np.float64), np.asarray(pd, dtype=np.float64)
    g = np.asarray(gammas, dtype=np.float64)
    if root_det.ndim != 2 or pd.shape != root_det.shape or not len(d2_scans) == len(alphas) == len(g) == len(pd) \
            or any(len(scans) != root_det.shape[1] for scans in d2_scans):
        raise ValueError(f"assess_windows needs root_det and pd (T, n), T windows of n scans, T alphas and gammas; "
                         f"got root_det {root_det.shape}, pd {pd.shape}, {len(d2_scans)} windows, {len(alphas)} "
                         f"alphas, {len(g)} gammas")
    T, n = root_det.shape
    if T == 0:
        return []
    sigma_n, volume, thr_cg = _window_gates(root_det, g, nz)
    flat, owner = _flatten([a for scans in d2_scans for a in scans])  # owner = t * n + j
    ng = np.bincount(owner[flat <= g[owner // n]], minlength=T * n).reshape(T, n)  # paper 002 (10): NG gate
    cg = np.bincount(owner[flat <= thr_cg.ravel()[owner]], minlength=T * n).reshape(T, n)
    return _window_tests(ng, cg, g, sigma_n, volume, pd, lam, nz, alphas)


def _window_gates(root_det: np.ndarray, g: np.ndarray, nz: int, sigma_n: np.ndarray | None = None
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sigma_n (T,), V_c (T,) and the CG thresholds (T, n) of T windows root_det (T, n) with TRD gates g (T,);
    sigma_n: root_det.mean(axis=1) when the caller has it."""
    if sigma_n is None:
        sigma_n = root_det.mean(axis=1)  # paper 002 (8): Sigma_n = mean |S(j)|^(1/2), per track
    volume = unit_ball_volume(nz) * g ** (0.5 * nz) * sigma_n  # paper 002 (8): V_c = c gamma^(nz/2) Sigma_n
    thr_cg = g[:, None] / constant_gate_scale(root_det, sigma_n[:, None], nz)  # paper 002 (9): CG gate
    return sigma_n, volume, thr_cg


def _window_tests(ng: np.ndarray, cg: np.ndarray, g: np.ndarray, sigma_n: np.ndarray, volume: np.ndarray,
                  pd: np.ndarray, lam: float, nz: int, alphas) -> list[RegimeTest]:
    """The RegimeTests of T windows from their NG and CG counts (T, n) (paper 002 §V steps 4-6)."""
    n = ng.shape[1]
    mu, pd_mean = lam * volume, pd.mean(axis=1)
    pdpg = pd_mean * gate_probability(g, nz)  # F_T is linear in P_D: the window's mixture uses mean P_D
    m = np.arange(int(max(ng.max(), cg.max())) + 1)[None, :]
    F_L = lost_cdf(m, mu[:, None])  # paper 002 (2)
    F_T = _tracking_from_lost(F_L, m, mu[:, None], pdpg[:, None])  # paper 002 (3)
    D = ks_distances_counts(np.concatenate([ng, cg]), np.concatenate([F_T, F_L]))  # both tests in one batch
    D_T, D_L = D[:len(ng)], D[len(ng):]  # paper 002 §V step 4: NG counts vs F_T, CG counts vs F_L(V_c)
    alphas = [float(a) for a in alphas]
    d_n = {a: critical_value(n, a) for a in set(alphas)}
    return [_test(n=n, alpha=a, d_n=d_n[a], D_T=dt, D_L=dl, gamma=gt, sigma_n=st, volume=vt, lam=lam, pd=pt,
                  counts_ng=ng[t], counts_cg=cg[t])
            for t, (a, dt, dl, gt, st, vt, pt) in enumerate(zip(
                alphas, D_T.tolist(), D_L.tolist(), g.tolist(), sigma_n.tolist(), volume.tolist(), pd_mean.tolist()))]


def _test(**fields) -> RegimeTest:
    """A RegimeTest of checked fields without running the frozen dataclass's __init__ (a tracker makes T per scan)."""
    new = object.__new__(RegimeTest)
    new.__dict__.update(fields)
    return new


# ------------------------------------------------------------------------------------------ rolled windows
WINDOW_LOW = 8
"""Smallest distances kept per scan in a rolled window [D]: a gate count below it is exact from them alone; a
count that reaches it in a scan with more measurements is recounted on the scan's full distances."""
ROW_FIXED = 3  # a rolled-window row: [|S|^(1/2), P_D, M, the WINDOW_LOW smallest d2 ascending]


def window_rows(root_det: np.ndarray, pd: np.ndarray, d2: np.ndarray, k: int = WINDOW_LOW) -> np.ndarray:
    """This scan's rolled-window row of T tracks, (T, 3 + k): |S|^(1/2) [m^n_z], P_D, the measurement count M and
    the k smallest squared distances of d2 (T, M) ascending (+inf where M < k)."""
    d2 = np.asarray(d2, dtype=np.float64)
    T, M = d2.shape
    rows = np.full((T, ROW_FIXED + k), np.inf)
    rows[:, 0], rows[:, 1], rows[:, 2] = root_det, pd, M
    if M:
        low = np.partition(d2, k - 1, axis=1)[:, :k] if M > k else d2
        rows[:, ROW_FIXED:ROW_FIXED + min(M, k)] = np.sort(low, axis=1)
    return rows


def roll_windows(windows: Sequence[np.ndarray | None], rows: np.ndarray, capacity: int) -> np.ndarray:
    """T windows (capacity, 3 + k) (None: no scan yet) with their rows of rows (T, 3 + k) appended and their oldest
    row dropped: (T, capacity, 3 + k), one new array (inputs untouched). A window's scans are its last rows, oldest
    first; the rows before them are padding (NaN |S|^(1/2), see `window_of_records`)."""
    T, width = rows.shape
    if T == 0:
        return np.zeros((0, capacity, width))
    empty = None
    old = []
    for w in windows:
        if w is None:
            empty = window_of_records((), width - ROW_FIXED, capacity) if empty is None else empty
            w = empty
        old.append(w)
    return np.concatenate([np.stack(old)[:, 1:], rows[:, None, :]], axis=1)


def window_holds(window: np.ndarray, length: int) -> bool:
    """True if a rolled window (capacity, 3 + k) holds exactly `length` scans: the row `length` from the end is a
    scan and the row before it padding (or there is none)."""
    first = len(window) - length
    return 0 <= first and (first == len(window) or not math.isnan(window[first, 0])) and \
        (first == 0 or math.isnan(window[first - 1, 0]))


def window_of_records(records: Sequence, k: int = WINDOW_LOW, capacity: int | None = None) -> np.ndarray:
    """The rolled window (capacity, 3 + k) of L <= capacity trackers.tracker ScanRecords (fields root_det or S, pd,
    d2), oldest first, after capacity - L padding rows (|S|^(1/2) and P_D NaN, M = 0, distances +inf); capacity
    None: L."""
    L = len(records)
    capacity = L if capacity is None else capacity
    if L > capacity:
        raise ValueError(f"window_of_records: {L} records exceed the capacity {capacity}")
    pad = np.full((capacity - L, ROW_FIXED + k), np.inf)
    pad[:, 0], pad[:, 1], pad[:, 2] = np.nan, np.nan, 0.0
    if not records:
        return pad
    root_det, _, pd = window_from_history(records, L)
    stored = np.array([np.nan if r.root_det is None else r.root_det for r in records], dtype=np.float64)
    root_det = np.where(np.isnan(stored), root_det, stored)
    return np.concatenate([pad] + [window_rows(root_det[i:i + 1], pd[i:i + 1], np.asarray(r.d2)[None, :], k)
                                   for i, r in enumerate(records)])


def assess_rolled(windows: np.ndarray, lam: float, nz: int, alphas, d2_of: Callable[[int, int], np.ndarray]
                  ) -> list[RegimeTest]:
    """assess_windows of T rolled windows of n scans, windows (T, n, 3 + k) (rows of window_rows), with the TRD
    gates gamma_best: the same RegimeTests, bit for bit. The gates are counted on each scan's k smallest distances;
    a count that reaches k in a scan with more measurements is recounted on that scan's full distances d2_of(t, j)
    (window t, scan j = 0..n-1, oldest first)."""
    root_det = np.ascontiguousarray(windows[:, :, 0])
    pd = np.ascontiguousarray(windows[:, :, 1])
    if len(root_det) == 0:
        return []
    sigma_n = root_det.mean(axis=1)  # paper 002 (8): Sigma_n, for the gate gamma_best and V_c
    g = np.atleast_1d(gamma_best_fast(lam * sigma_n, nz))
    sigma_n, volume, thr_cg = _window_gates(root_det, g, nz, sigma_n)
    ng = _low_counts(windows, np.broadcast_to(g[:, None], root_det.shape), d2_of)  # paper 002 (10): NG gate
    cg = _low_counts(windows, thr_cg, d2_of)  # paper 002 (9): CG gate
    return _window_tests(ng, cg, g, sigma_n, volume, pd, lam, nz, alphas)


def _low_counts(windows: np.ndarray, thr: np.ndarray, d2_of: Callable[[int, int], np.ndarray]) -> np.ndarray:
    """(T, n) int64 measurements with d2 <= thr (T, n) per scan of rolled windows (T, n, 3 + k)."""
    low, size = windows[:, :, ROW_FIXED:], windows[:, :, 2].astype(np.int64)
    k = low.shape[2]
    counts = np.minimum((low <= thr[:, :, None]).sum(axis=2), size)  # int64: sums of bools, minimum of int64s
    for t, j in zip(*np.nonzero((counts == k) & (size > k))):  # the k kept are all in: count the scan's full d2
        counts[t, j] = np.count_nonzero(np.asarray(d2_of(int(t), int(j))) <= thr[t, j])
    return counts


# ------------------------------------------------------------------------------------------ per track
@dataclass(frozen=True)
class RegimeConfig:
    """n: window [scans] (the start value when adaptive); alphas: significance levels, the first used, the
    others the raised CIs of the adaptive rule; adaptive: paper 002 §V-F; step, n_min, n_max: its n moves
    [D] (reference: 5, 5, 500); flips: both/neither alternations (or a bound hit) before the CI is raised [D]."""

    n: int = 50
    alphas: tuple[float, ...] = (0.05, 0.01)
    adaptive: bool = False
    step: int = 5
    n_min: int = 5
    n_max: int = 500
    flips: int = 3

    def __post_init__(self) -> None:
        if not 1 <= self.n_min <= self.n <= self.n_max or self.step < 1 or self.flips < 1:
            raise ValueError(f"RegimeConfig needs 1 <= n_min <= n <= n_max, step >= 1, flips >= 1; got {self}")
        if not self.alphas or not all(0 < a < 1 for a in self.alphas):
            raise ValueError(f"RegimeConfig.alphas must be in (0, 1), got {self.alphas}")

    @property
    def longest(self) -> int:
        """Scans of history the detector may read."""
        return self.n_max if self.adaptive else self.n


@dataclass(frozen=True)
class RegimeState:
    """A track's detector state: label in LABELS; n and level (index into RegimeConfig.alphas) for the next
    test; flips and unique_run: the adaptive rule's counters; last: the latest RegimeTest (None before one);
    window: in a tracker, the track's rolled window (RegimeConfig.longest, 3 + k): its last scans (rows of
    window_rows, oldest first) after padding rows (roll_windows); None elsewhere."""

    label: str = "unknown"
    n: int = 0
    level: int = 0
    flips: int = 0
    unique_run: int = 0
    last: RegimeTest | None = None
    window: np.ndarray | None = field(default=None, compare=False, repr=False)


def initial_state(cfg: RegimeConfig) -> RegimeState:
    """A new track's detector state: label 'unknown', window cfg.n, the first CI."""
    return RegimeState(n=cfg.n)


def advance(state: RegimeState, test: RegimeTest | None, cfg: RegimeConfig,
            window: np.ndarray | None = None) -> RegimeState:
    """The state after `test` (None: too little history, label 'unknown'), holding the rolled `window`
    (capacity, 3 + k) (roll_windows; None: the state's own); with cfg.adaptive the paper's rule (§V-F): both
    accepted -> n + step; neither -> n - step; one -> keep n; `cfg.flips` failures in a row (both and neither
    alternating, or a bound of n reached) -> the next CI of cfg.alphas [D]; a unique verdict held for n scans ->
    back one CI level [D]."""
    held = {} if window is None else {"window": window}
    if test is None:
        return state if state.label == "unknown" and not held else _with(state, label="unknown", **held)
    if not cfg.adaptive:
        return _with(state, label=test.label, last=test, **held)
    previous = state.last.verdict if state.last is not None else None
    state = _with(state, label=test.label, last=test, **held)
    return _adapt(state, test.verdict, previous, cfg)


def _with(state: RegimeState, **fields) -> RegimeState:
    """`dataclasses.replace` of a RegimeState without re-running __init__ (once per track and scan)."""
    new = object.__new__(RegimeState)
    new.__dict__.update(state.__dict__)
    new.__dict__.update(fields)
    return new


def _adapt(state: RegimeState, verdict: str, previous: str | None, cfg: RegimeConfig) -> RegimeState:
    n, level, flips, run = state.n, state.level, state.flips, state.unique_run
    if verdict in ("tracking", "track-lost"):  # paper 002 §V-F ii): one regime, keep n
        flips, run = 0, run + 1
        if level > 0 and run >= n:
            level, run = level - 1, 0
        return replace(state, level=level, flips=flips, unique_run=run)
    grow = verdict == "both"  # paper 002 §V-F i) both -> increase n; iii) neither -> decrease n
    target = n + cfg.step if grow else n - cfg.step
    stuck = target > cfg.n_max or target < cfg.n_min
    alternating = previous in ("both", "neither") and previous != verdict
    flips = flips + 1 if (stuck or alternating) else 0
    if flips >= cfg.flips and level + 1 < len(cfg.alphas):
        level, flips = level + 1, 0  # paper 002 §V-F: no n gives a unique regime -> increase the CI
    return replace(state, n=min(max(target, cfg.n_min), cfg.n_max), level=level, flips=flips, unique_run=0)


def alpha_of(state: RegimeState, cfg: RegimeConfig) -> float:
    """The significance level of the state's next test."""
    return cfg.alphas[min(state.level, len(cfg.alphas) - 1)]


# ------------------------------------------------------------------------------------------ Track.history
def window_from_history(history: Sequence, n: int) -> tuple[np.ndarray, list[np.ndarray], np.ndarray]:
    """(root_det (n,), d2_scans (n arrays), pd (n,)) of the last n ScanRecords of a trackers.tracker Track
    (fields S, d2, pd), for assess_window. Needs len(history) >= n."""
    recs = history[len(history) - n:]
    root_det = np.sqrt(np.linalg.det(np.stack([r.S for r in recs])))
    return root_det, [r.d2 for r in recs], np.array([r.pd for r in recs], dtype=np.float64)


def windows_from_histories(histories: Sequence[Sequence], n: int) -> tuple[np.ndarray, list, np.ndarray]:
    """window_from_history of T histories with one window length n: (root_det (T, n), d2_scans T lists of n
    arrays, pd (T, n)), for assess_windows; a record's stored root_det (|S|^(1/2)) is used where it has one.
    Every history needs len >= n."""
    recs = [h[len(h) - n:] for h in histories]
    stored = [[getattr(r, "root_det", None) for r in rs] for rs in recs]
    root_det = np.array([[np.nan if v is None else v for v in row] for row in stored], np.float64).reshape(len(recs), n)
    missing = np.isnan(root_det)
    if missing.any():  # records without a stored |S|^(1/2): from S, as window_from_history does
        root_det[missing] = np.sqrt(np.linalg.det(np.stack([r.S for rs in recs for r in rs]))).reshape(-1, n)[missing]
    pd = np.array([[r.pd for r in rs] for rs in recs], dtype=np.float64).reshape(len(recs), n)
    return root_det, [[r.d2 for r in rs] for rs in recs], pd


# ------------------------------------------------------------------------------------------ a scan series
@dataclass(frozen=True, eq=False)
class RegimeSeries:
    """The detector run scan by scan over K scans: verdict and label (K,) str ('' / 'unknown' before a full
    window); D_T, D_L, d_n, gamma, sigma_n, volume (K,) float (NaN there); n (K,) int64 window used (0 there)."""

    verdict: np.ndarray
    label: np.ndarray
    D_T: np.ndarray
    D_L: np.ndarray
    d_n: np.ndarray
    gamma: np.ndarray
    sigma_n: np.ndarray
    volume: np.ndarray
    n: np.ndarray


def regime_series(root_det: np.ndarray, d2: np.ndarray, offsets: np.ndarray, pd: np.ndarray, lam: float, nz: int,
                  cfg: RegimeConfig, gamma: float | None = None) -> RegimeSeries:
    """Run the detector (fixed or adaptive n, cfg) over a series of K scans: root_det (K,) |S(k)|^(1/2); d2 (N,)
    the distances of every measurement, scan k's in d2[offsets[k]:offsets[k + 1]] (offsets (K + 1,)); pd (K,)
    the tracker's P_D; gamma: a fixed TRD gate (None: gamma_best per window)."""
    K = len(root_det)
    scans = [np.sort(d2[offsets[k]:offsets[k + 1]]) for k in range(K)]
    out = {f: np.full(K, np.nan) for f in ("D_T", "D_L", "d_n", "gamma", "sigma_n", "volume")}
    verdict, label, used = np.full(K, "", dtype=object), np.full(K, "unknown", dtype=object), np.zeros(K, np.int64)
    state = initial_state(cfg)
    for k in range(K):
        a = k + 1 - state.n
        if a < 0:
            state = advance(state, None, cfg)
            continue
        test = assess_window(root_det[a:k + 1], scans[a:k + 1], pd[a:k + 1], lam, nz, alpha_of(state, cfg), gamma,
                             presorted=True)
        state = advance(state, test, cfg)
        verdict[k], label[k], used[k] = test.verdict, test.label, test.n
        for f in out:
            out[f][k] = getattr(test, f)
    return RegimeSeries(verdict=verdict, label=label, n=used, **out)
