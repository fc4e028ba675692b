"""Smooth variable structure filters in PDA form: the standard SVSF (thesis ch. 2) and the generalised,
covariance-modified SVSF (thesis ch. 3, restated in ch. 4 §4.4). The GVBL-SVSF of ch. 4 is in `gvbl.py`.

Shared pieces (also used by `gvbl.py`):
* `svsf_gain_factor(E, e, psi)`: the diagonal of diag(E o sat(e, psi)) diag(e)^-1, thesis (2.10)/(3.12);
* `Partition`: the measured / unmeasured split of the state, H = [H1 0] (thesis (3.29)-(3.35), (4.31)-(4.32))
  and the reduced-order maps Phi22 Phi12^+ and Phi12^+ read from the transition Jacobian F that `predict`
  stored in the state (for NCV Phi12 = dt I, Phi22 = I; for the 5-D CT model Phi12 is 2 x 3 and its
  Moore-Penrose pseudo-inverse is used [D], in the GVBL-SVSF's E_y and Psi_y only: the
  generalised SVSF's lower gain needs Phi12 invertible, see `GeneralisedSVSF`);
* `generalised_covariance`: thesis (4.37), which equals the Joseph form for any gain (S = H1 P11 H1^T + R);
* `estimate_mse`: the default covariance of `svsf` and `gc-svsf` (below).

Every update follows the PDA form of thesis §2.1.5/§3.5.1: the a priori measurement error is the combined
innovation e_{z,k|k-1} := sum_i beta_i nu_i (2.27)/(3.54); the gain is computed from it and the stored
a posteriori error e_{z,k-1|k-1} (`FilterState.e_post`); the covariance is the PDA combination (4.16)-(4.17)
with the filter's single-measurement covariance P*; the new memory is e_{z,k|k} = (I - H K) e_{z,k|k-1} (3.65).

Covariance ([R], `covariance = "mse"`, default): (4.37) = P_kf + (K - K_kf) S (K - K_kf)^T is the error
covariance of a gain that does not depend on the innovation, i.e. its average over e ~ N(0, S). The fixed-layer
gain |e| / psi does depend on it: when |e| << psi the gain is near 0, P* ~ P and P grows with Q alone, however
well the target is measured (LiDAR convoy: gates of 1,100-1,500 m^2 against the KF's 20, issue 17). "mse" is
the mean-square error about the SVSF estimate given the innovations, P_kf + d d^T with d the distance from the
Kalman estimate (the PDA mixture of these for soft weights, `estimate_mse`): the KF's P when the two agree,
larger when the SVSF's correction departs from the KF's. It changes P only, never x, the gain or the memory.
"joseph" keeps (2.12)/(4.37) as printed.
M = 0 or beta0 = 1 (an empty gate, or no weight on any measurement) returns the prediction unchanged
(`memory_after_miss = "keep"`, default: what "no update" means in (4.16)), or the prediction with the memory
e_{z,k-1|k-1} set to 0 ("reset": the next gain starts without memory, as at birth). [D]: the thesis (§2.1.5,
§3.5.1) defines the memory only after an update; `after_miss` below.
Units: positions m, velocities m/s, boundary-layer widths in the units of the component they bound.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, fields, replace

import numpy as np

from roadtrack.trackers.errors import FilterError
from roadtrack.trackers.filters.base import (ModelFilter, batch_weights, check_covariance, check_weights, cholesky,
                                   combined_innovation, pda_covariance, sum_in_order, symmetrise, weighted_R,
                                   weighted_outer)
from roadtrack.trackers.filters.params import ModelParams
from roadtrack.trackers.params import POSITIVE, ParamError, param
from roadtrack.trackers.state import FilterState, StateRows, derive, derive_frozen, freeze, rows_of, updated_rows

EY_MEMORY = ("a_priori", "a_posteriori")
COVARIANCES = ("mse", "joseph", "short")
MEMORY_AFTER_MISS = ("keep", "reset")
ARTIFICIAL_PDA = ("per_measurement", "combined")


# ------------------------------------------------------------------------------------------ shared maths
def svsf_gain_factor(E: np.ndarray, e: np.ndarray, psi: np.ndarray) -> np.ndarray:
    """Diagonal of diag(E o sat(e, psi)) diag(e)^-1 (m,): E_j / psi_j inside the layer (|e_j| <= psi_j) and
    E_j / |e_j| outside. E, e, psi (m,), psi > 0.

    Written as E / max(|e|, psi): identical to E_j sat(e_j / psi_j) / e_j for e_j != 0, and equal to its
    limit E_j / psi_j at e_j = 0, which is the thesis's division guard (§2.1.3 after (2.10))."""
    return E / np.maximum(np.abs(e), psi)  # (2.10), (3.12): E o sat(e / psi) / e


def generalised_covariance(P: np.ndarray, K: np.ndarray, H: np.ndarray, S: np.ndarray) -> np.ndarray:
    """P - K H P - P H^T K^T + K S K^T (n, n) for any gain K (n, m); S = H P H^T + R (m, m)."""
    KHP = K @ H @ P
    return symmetrise(P - KHP - KHP.T + K @ S @ K.T)  # (4.37), (3.45)-(3.49): generalised SVSF covariance


def estimate_mse(P: np.ndarray, H: np.ndarray, R: np.ndarray, x_pred: np.ndarray, x: np.ndarray, nu: np.ndarray,
                 beta: np.ndarray, beta0: float) -> np.ndarray:
    """Mean-square error (n, n) about the estimate x (n,) of the PDA posterior of the prior N(x_pred, P (n, n)):
    beta0 [P + d0 d0^T] + sum_i beta_i [P_kf + d_i d_i^T], d0 = x - x_pred, d_i = x - x_pred - K_kf nu_i,
    with the Kalman gain K_kf = P H^T S^-1 and P_kf = P - K_kf S K_kf^T, S = H P H^T + R.

    nu (M, m) are the real measurements' innovations, H (m, n), R (m, m), beta (M,), beta0. With one
    measurement and x = x_pred + K e this is P_kf + (K - K_kf) e e^T (K - K_kf)^T, i.e. (4.37) written as
    P_kf + (K - K_kf) S (K - K_kf)^T with S replaced by the realised e e^T: the SVSF gain is a function of e,
    so (4.37) (its average over e ~ N(0, S) for a FIXED gain) is not its error covariance given e. For
    x = x_pred + K_kf nu_c it is the PDA covariance (4.16)-(4.17) with P* = P_kf."""
    S = symmetrise(H @ P @ H.T + R)
    K_kf = np.linalg.solve(S, H @ P).T  # (4.73): the Kalman gain, the optimal-layer SVSF gain
    P_kf = symmetrise(P - K_kf @ S @ K_kf.T)
    d0 = x - x_pred
    D = d0 - nu @ K_kf.T  # (M, n): x minus each measurement's Kalman estimate
    return symmetrise(beta0 * (P + np.outer(d0, d0)) + (1.0 - beta0) * P_kf + (D.T * beta) @ D)


@dataclass(frozen=True)
class Partition:
    """Measured / unmeasured split of the state for H = [H1 0] up to a column permutation.

    u (m,) state indices seen by the measurement, in measurement order; l (n - m,) the others;
    H1 (m, m) invertible. Built from the measurement Jacobian by `Partition.of(H)`."""

    u: np.ndarray
    l: np.ndarray
    H1: np.ndarray

    @staticmethod
    def of(H: np.ndarray) -> "Partition":
        """The partition of H (m, n) (read-only arrays; made once per distinct H, `_partition_of`)."""
        H = np.asarray(H, dtype=np.float64)
        return _partition_of(H.shape, H.tobytes())

    @staticmethod
    def _of(H: np.ndarray) -> "Partition":
        m, n = H.shape
        used = np.flatnonzero(np.any(H != 0.0, axis=0))
        if used.size != m:
            raise FilterError(f"SVSF partition needs H = [H1 0] with {m} measured states, H uses {used.size}")
        H1 = H[:, used]
        if abs(np.linalg.det(H1)) < 1e-12:
            raise FilterError("SVSF partition needs an invertible H1 (thesis (3.29))")
        return Partition(u=used, l=np.setdiff1d(np.arange(n), used), H1=H1)

    def maps(self, F: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        """(Phi22 Phi12^+ (n-m, m), Phi12^+ (n-m, m)) from the transition Jacobian F (n, n) of the last predict.

        With T = blockdiag(H1, I): Phi = T F T^-1, so Phi12 = H1 F_ul and Phi22 = F_ll. Phi12^+ is the
        Moore-Penrose pseudo-inverse (the inverse for NCV, where Phi12 = dt I)."""
        if F is None:
            raise ValueError("SVSF update needs s_pred.F, the transition Jacobian stored by predict")
        Phi12 = self.H1 @ F[np.ix_(self.u, self.l)]  # (4.31)-(4.32) partition, T = blockdiag(H1, I)
        Phi22 = F[np.ix_(self.l, self.l)]
        Phi12_pinv = np.linalg.pinv(Phi12)  # §2.3.5 [D]: Phi12^+ (Phi12^-1 for NCV)
        return Phi22 @ Phi12_pinv, Phi12_pinv

    def assemble(self, K_u: np.ndarray, K_l: np.ndarray) -> np.ndarray:
        """The full gain K (n, m) from its measured (m, m) and unmeasured (n-m, m) rows."""
        K = np.zeros((self.u.size + self.l.size, K_u.shape[1]))
        K[self.u] = K_u
        K[self.l] = K_l
        return K  # (4.35): K = [K_u; K_l]


@functools.lru_cache(maxsize=64)
def _partition_of(shape: tuple[int, int], data: bytes) -> Partition:
    """Partition._of of the H (shape) whose float64 bytes are `data` (the filters ask for the same H every scan)."""
    part = Partition._of(np.frombuffer(data, dtype=np.float64).reshape(shape).copy())
    freeze(part.u, part.l, part.H1)
    return part


def maps_many(part: Partition, Fs: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`Partition.maps` of A transition Jacobians Fs (n, n) and the pseudo-inverse of the first map:
    (M = Phi22 Phi12^+, Phi12^+, M^+), each 2-D ((n-m, m), (n-m, m), (m, n-m)) when one F is shared by every
    track (NCV: mapped once), else stacked per track ((A, n-m, m), (A, n-m, m), (A, m, n-m); CT)."""
    F0 = Fs[0]
    if all(F is F0 or np.array_equal(F, F0) for F in Fs):
        M, Phi12_pinv = part.maps(F0)
        return M, Phi12_pinv, np.linalg.pinv(M)
    F = np.array(Fs)
    Phi12 = part.H1 @ F[:, part.u][:, :, part.l]  # (4.31)-(4.32) partition, T = blockdiag(H1, I)
    Phi22 = F[:, part.l][:, :, part.l]
    Phi12_pinv = np.linalg.pinv(Phi12)  # §2.3.5 [D]: Phi12^+ (Phi12^-1 for NCV)
    M = Phi22 @ Phi12_pinv
    return M, Phi12_pinv, np.linalg.pinv(M)


def apply_rows(M: np.ndarray, v: np.ndarray) -> np.ndarray:
    """M v of each row of v (A, k): M (j, k) shared by every track or (A, j, k) per track -> (A, j)."""
    return v @ M.T if M.ndim == 2 else np.einsum("ajk,ak->aj", M, v)


def lower_error(M: np.ndarray, Phi12_pinv: np.ndarray, e: np.ndarray, e_post: np.ndarray, gamma_y: float,
                memory: str) -> tuple[np.ndarray, np.ndarray]:
    """(e_y (n-m,), E_y (n-m,)) for the unmeasured partition: e_y = Phi22 Phi12^+ e and
    E_y = |e_y| + gamma_y |Phi12^+ e| (thesis form, a priori e in both terms) or gamma_y |Phi12^+ e_post|
    (memory = "a_posteriori", Habibi's original reading [D])."""
    e_y = M @ e  # (3.37): a priori lower error e_y = Phi22 Phi12^-1 e_z
    mem = e if memory == "a_priori" else e_post
    return e_y, np.abs(e_y) + gamma_y * np.abs(Phi12_pinv @ mem)  # (4.34) E_y


def after_miss(s_pred: FilterState, memory: str) -> FilterState:
    """The state after a scan without update (M = 0 or beta0 = 1) for `memory_after_miss` = memory: s_pred itself
    ("keep") or s_pred with the SVSF memories e_post (m,) and, if it has one, e_vel (m,) set to 0 ("reset")."""
    if memory == "keep":
        return s_pred  # (4.16) with beta0 = 1: no update, e_{z,k-1|k-1} of (2.10)/(4.30) kept [D]
    zeros = {"e_post": np.zeros(s_pred.e_post.shape)}
    if getattr(s_pred, "e_vel", None) is not None:
        zeros["e_vel"] = np.zeros(s_pred.e_vel.shape)
    return derive(s_pred, **zeros)  # [D] e_{z,k-1|k-1} := 0 after a miss (thesis §2.1.5, §3.5.1 silent)


def check_memory_after_miss(owner: str, memory: str) -> None:
    """ValueError (one line) unless memory is one of MEMORY_AFTER_MISS."""
    if memory not in MEMORY_AFTER_MISS:
        raise ValueError(f"{owner} memory_after_miss must be one of {MEMORY_AFTER_MISS}, got {memory!r}")


def promote_state(cls: type, s: FilterState) -> FilterState:
    """s as an instance of the FilterState subclass `cls` (extra fields at their defaults)."""
    if isinstance(s, cls):
        return s
    return cls(**{f.name: getattr(s, f.name) for f in fields(FilterState)})


# ----------------------------------------------------------------------------------------- standard SVSF
@dataclass(frozen=True, eq=False)
class SVSFState(FilterState):
    """FilterState of the standard SVSF with artificial velocity measurements.

    z_prev (m,): projected measurement z^a of the last update (2.32) (NaN before the first update);
    tau [s]: time since that update (predict adds dt); e_vel (m,): the a posteriori error of the artificial
    velocity components (the position part is `e_post`)."""

    z_prev: np.ndarray | None = None
    tau: float = 0.0
    e_vel: np.ndarray | None = None

    def __post_init__(self) -> None:
        super().__post_init__()
        for name in ("z_prev", "e_vel"):
            if getattr(self, name) is not None:
                a = np.array(getattr(self, name), dtype=np.float64)
                a.setflags(write=False)
                object.__setattr__(self, name, a)


def svsf_state(x: np.ndarray, P: np.ndarray, e_post: np.ndarray, F: np.ndarray | None, info: dict,
               z_prev: np.ndarray | None, tau: float, e_vel: np.ndarray | None) -> SVSFState:
    """SVSFState of read-only arrays without __init__, its fields set one by one in their order (as
    state.frozen_state: half of derive_frozen's cost; the batched predict and update make T per scan)."""
    new = object.__new__(SVSFState)
    d = new.__dict__
    d["x"], d["P"], d["e_post"], d["F"], d["info"], d["z_prev"], d["tau"], d["e_vel"] = (x, P, e_post, F, info, z_prev,
                                                                                          tau, e_vel)
    return new


@dataclass(frozen=True)
class SVSF(ModelFilter):
    """Standard SVSF (thesis ch. 2, §2.1.3 (2.7)-(2.13); PDA form §2.1.5 (2.27)-(2.34)).

    K = H^+ diag[(|e_{k|k-1}| + gamma |e_{k-1|k-1}|) o sat(e_{k|k-1}, psi)] diag(e_{k|k-1})^-1   (2.30)
    P: `estimate_mse` ("mse", default, module docstring), P* = (I - K H) P (I - K H)^T + K R K^T ("joseph",
    (2.31)) or (I - K H) P ("short", (2.54)/(2.89)), the last two combined by (4.16)-(4.17). "mse" uses the
    real position measurement only: the artificial velocity measurement adds no information beyond z and
    z_prev, which the prior already holds.

    Fewer measurements than states (m < n), `unmeasured`:
    * "pinv": the literal (2.10)/(2.30) with H^+. For H = [I 0], H^+ = H^T, so the velocity rows of K are
      zero and velocities are never corrected (they keep their initial value under NCV). This is what the
      ch. 2 text prints.
    * "artificial" (default): the artificial-measurement construction of [17], which the thesis names in
      §4.5.1 ("In [17], an artificial measurement construction approach is suggested to form a full
      measurement matrix"): z_bar = [z; (z - z_prev) / tau], H_bar = [H; H_v] (= I for NCV),
      R_bar = [[R, R/tau], [R/tau, 2R/tau^2]] (differenced noise; its correlation in time is ignored).
      The thesis text supports "pinv" literally, but its ch. 2 velocity RMSEs (close to the KF's, Table 2.4)
      and the ch. 3 PDA-SVSF baseline (velocity RMSE 5.9 m/s ~ sqrt(2) sigma_w / Ts, Table 3.1) are only
      consistent with velocities being corrected, i.e. with the artificial measurement; hence the default.
      In PDA form z_prev is the projected measurement z^a = e_{z,k|k-1} + H x_{k|k-1} of the last update
      (2.32), tau the time since it (so after missed scans the difference spans them), and every validated
      measurement gets its own augmented innovation nu_bar_i = [nu_i; (z_hat + nu_i - z_prev)/tau - H_v x],
      from which both forms below build the PDA spread term (4.17). The first update (no z_prev) uses the
      position rows only.

    `artificial_pda`, how the artificial velocity enters e_{z,k|k-1} under PDA (the thesis does not say):
    * "per_measurement" (default): e_{z,k|k-1} = sum_i beta_i nu_bar_i, the combined innovation (2.27) of
      the augmented innovations, so the velocity part carries 1 - beta0 of the differenced position
      (1 - beta0)((z_hat - z_prev)/tau - H_v x) + nu_c / tau: the reading that treats the artificial
      measurement like a real one, each hypothesis with its own.
      The spread term (4.17) ("joseph", "short") is sum_{i=1..M} beta_i nu_bar_i nu_bar_i^T - e e^T: the spread of the
      hypotheses' augmented innovations about e, the miss hypothesis at nu_bar_0 = 0 (no measurement, no
      artificial one).
    * "combined": one artificial measurement from the projected measurement z^a = z_hat + nu_c (2.32):
      e_{z,k|k-1} = [nu_c; (z^a - z_prev)/tau - H_v x], i.e. (3.63)'s projected measurement differenced; the
      reading in which z^a stands for the scan's measurement, as it does for z_prev. z^a = sum_{i=0..M} beta_i
      (z_hat + nu_i) (nu_0 = 0), so e = sum_{i=0..M} beta_i nu_bar_i with the miss hypothesis's artificial velocity
      nu_bar_0 = [0; (z_hat - z_prev)/tau - H_v x]; the spread term (4.17) is the spread of these M + 1 about e,
      B [sum_i beta_i nu_i nu_i^T - nu_c nu_c^T] B^T with B = [I; I/tau] (`combined_form`).
    The two agree when beta0 = 0 (state, covariance and memories).

    gamma: SVSF memory in [0, 1); psi (m,) [m]: the fixed position layer half widths (the registry default
    3 sigma_w is [D]: ch. 2-3 give no value); psi_v [m/s]: the layer of the artificial velocity components,
    None for 3 sqrt(R_bar_vv) = 3 sqrt(2) sigma_w / tau. The sign(e / psi) printed in (2.10) is the limit
    psi -> 0 (e.g. psi = 1e-6): full correction plus gamma times the memory on every scan.
    memory_after_miss: "keep" (default) or "reset" the memories e_post and e_vel after a scan without update
    (module docstring). Needs a linear position measurement (H = [H1 0]) and, for "artificial", a motion model whose
    unmeasured states are exactly the velocities (NCV)."""

    motion: object
    measurement: object
    gamma: float = 0.1
    psi: tuple[float, ...] = (1.0, 1.0)
    psi_v: float | None = None
    unmeasured: str = "artificial"
    covariance: str = "mse"
    artificial_pda: str = "per_measurement"
    memory_after_miss: str = "keep"

    def __post_init__(self) -> None:
        m = self.measurement.ndim
        check_memory_after_miss("SVSF", self.memory_after_miss)
        if self.artificial_pda not in ARTIFICIAL_PDA:
            raise ValueError(f"SVSF artificial_pda must be one of {ARTIFICIAL_PDA}, got {self.artificial_pda!r}")
        if not (0.0 <= self.gamma < 1.0):
            raise ValueError(f"SVSF gamma must be in [0, 1), got {self.gamma}")
        if len(self.psi) != m or not all(math.isfinite(p) and p > 0 for p in self.psi):
            raise ValueError(f"SVSF psi must be {m} finite widths > 0, got {self.psi}")
        if self.psi_v is not None and not (math.isfinite(self.psi_v) and self.psi_v > 0):
            raise ValueError(f"SVSF psi_v must be a finite width > 0 or None, got {self.psi_v}")
        if self.unmeasured not in ("artificial", "pinv") or self.covariance not in COVARIANCES:
            raise ValueError(f"SVSF unmeasured must be artificial|pinv and covariance {'|'.join(COVARIANCES)}, "
                             f"got {self.unmeasured!r}, {self.covariance!r}")
        if self.unmeasured == "artificial" and not (self.measurement.linear and self.motion.linear
                                                    and len(self.motion.velocity) == m
                                                    and self.motion.ndim == 2 * m):
            raise ValueError("SVSF artificial measurements need a linear position measurement and an NCV motion "
                             "model whose unmeasured states are the velocities")

    def initial_state(self, x0: np.ndarray, P0: np.ndarray) -> SVSFState:
        s = super().initial_state(x0, P0)
        m = self.measurement.ndim
        return SVSFState(x=s.x, P=s.P, e_post=s.e_post, z_prev=np.full(m, np.nan), tau=0.0, e_vel=np.zeros(m))

    def predict(self, s: FilterState, dt: float) -> SVSFState:
        """(E)KF predict (2.7)-(2.8); also advances tau, the time since the last projected measurement."""
        s = promote_state(SVSFState, s)
        return replace(super().predict(s, dt), tau=s.tau + float(dt))

    def layer(self, s_pred: FilterState) -> np.ndarray:
        """The fixed position layer psi (m,) [m]."""
        return np.array(self.psi, dtype=np.float64)

    def layers_many(self, preds: list[FilterState], m: int) -> np.ndarray:
        """`layer` of T predicted states at once: the fixed layer in every row (T, m) [m]."""
        return np.tile(self.layer(None), (len(preds), 1))

    def augmented(self, s: SVSFState, nu: np.ndarray, R: np.ndarray | None = None
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(H_bar (2m, n), R_bar (2m, 2m), nu_bar (M, 2m), e_prev (2m,), psi (2m,)): the artificial velocity
        measurement of [17] appended to the position measurement, for the innovations nu (M, m); R (m, m) the
        position noise (None: the measurement model's)."""
        m, tau = self.measurement.ndim, s.tau
        H, R = self.measurement_jacobian(s), (self.measurement.R if R is None else R)
        Hv = np.zeros((m, len(s.x)))
        Hv[range(m), self.motion.velocity] = 1.0
        z_hat = self.measurement.h(s.x, self.motion)
        R_bar = np.block([[R, R / tau], [R / tau, 2.0 * R / tau ** 2]])  # [17]: covariance of [z; (z - z_prev)/tau]
        nu_bar = np.hstack([nu, (z_hat + nu - s.z_prev) / tau - Hv @ s.x])  # per-measurement augmented innovations
        e_prev = np.concatenate([s.e_post, s.e_vel if s.e_vel is not None else np.zeros(m)])
        psi_v = self.psi_v if self.psi_v is not None else 3.0 * np.sqrt(np.diag(R_bar)[m:])  # §2.3 [D] 3 sigma
        psi = np.concatenate([np.array(self.psi, dtype=np.float64), np.broadcast_to(psi_v, (m,))])
        return np.vstack([H, Hv]), R_bar, nu_bar, e_prev, psi  # [17] artificial measurement: H_bar = [H; H_v]

    def combined_form(self, s: SVSFState, nu: np.ndarray, nu_c: np.ndarray, z_a: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray]:
        """artificial_pda = "combined": (e (2m,), nu_s (M, 2m)) for the innovations nu (M, m), their combination
        nu_c (m,) and the projected measurement z^a = z_hat + nu_c (m,).

        e = e_{z,k|k-1} = [nu_c; (z^a - z_prev) / tau - H_v x], one artificial velocity from z^a (2.32). With the
        hypotheses i = 0..M of (4.16) (0: no measurement, nu_0 = 0, projected measurement z_hat) and their augmented
        innovations nu_bar_i = [nu_i; (z_hat + nu_i - z_prev) / tau - H_v x], e = sum_{i=0..M} beta_i nu_bar_i. The
        spread term (4.17) is theirs about e, sum_{i=0..M} beta_i (nu_bar_i - e)(nu_bar_i - e)^T
        = B [sum_i beta_i nu_i nu_i^T - nu_c nu_c^T] B^T with B = [I; I / tau]; `pda_covariance` computes it from
        nu_s_i = nu_bar_i - nu_bar_0 = [nu_i; nu_i / tau] (its miss hypothesis is at 0)."""
        e_v = (z_a - s.z_prev) / s.tau - s.x[list(self.motion.velocity)]  # (2.32) z^a differenced, [17]
        return np.concatenate([nu_c, e_v]), np.hstack([nu, nu / s.tau])  # (4.17) spread from the combined form [D]

    def update(self, s_pred: FilterState, nu: np.ndarray, beta: np.ndarray, beta0: float,
               R: np.ndarray | None = None) -> FilterState:
        """PDA-form SVSF update; nu (M, m) innovations, beta (M,), beta0 (see module docstring); R (M, m, m) the
        detections' own covariances, whose beta-weighted mean replaces the model's R (`weighted_R`, [D]), or None."""
        m = self.measurement.ndim
        nu, beta, beta0 = check_weights(nu, beta, beta0, m)
        if nu.shape[0] == 0 or beta0 == 1.0:
            return after_miss(s_pred, self.memory_after_miss)  # (4.16) with beta0 = 1: no update
        s = promote_state(SVSFState, s_pred)
        H0, R0 = self.measurement_jacobian(s), (self.measurement.R if R is None else weighted_R(R, beta[None])[0])
        z_a = self.measurement.h(s.x, self.motion) + combined_innovation(nu, beta)  # (2.32) projected measurement
        with_vel = (self.unmeasured == "artificial" and s.tau > 0.0 and s.z_prev is not None
                    and np.isfinite(s.z_prev).all())
        H, R, nu_b, e_prev, psi = (self.augmented(s, nu, R0) if with_vel
                                   else (H0, R0, nu, s.e_post, np.array(self.psi, dtype=np.float64)))
        nu_c = combined_innovation(nu_b, beta)  # (2.27) e_{z,k|k-1} := combined innovation
        if with_vel and self.artificial_pda == "combined":  # (2.32) one artificial measurement from z^a [D]
            nu_c, nu_b = self.combined_form(s, nu, nu_c[:m], z_a)
        E = np.abs(nu_c) + self.gamma * np.abs(e_prev)  # (2.10) |e_{k|k-1}| + gamma |e_{k-1|k-1}|
        K = np.linalg.pinv(H) * svsf_gain_factor(E, nu_c, psi)  # (2.30) K = H^+ diag(E o sat(e/psi)) diag(e)^-1
        x = s.x + K @ nu_c  # (2.29)
        if not np.isfinite(x).all():
            raise FilterError("SVSF updated state x is not finite")
        if self.covariance == "mse":
            P = estimate_mse(s.P, H0, R0, s.x, x, nu, beta, beta0)  # [R] MSE about x given the innovations
        else:
            I_KH = np.eye(len(s.x)) - K @ H
            P_star = (I_KH @ s.P @ I_KH.T + K @ R @ K.T if self.covariance == "joseph"  # (2.31)/(2.12) Joseph
                      else I_KH @ s.P)  # (2.54)/(2.89) short form as printed
            P = pda_covariance(s.P, symmetrise(P_star), K, nu_b, beta, beta0)  # (4.16)-(4.17), SVSF P*, spread of nu_b
        check_covariance(P, "SVSF updated covariance P")
        e_post = nu_c - H @ (K @ nu_c)  # (2.34)/(3.65) e_{z,k|k} = (I - H K) e_{z,k|k-1}
        info = {"psi_z": psi[:m], "chatter": np.maximum(0.0, np.abs(nu_c[:m]) - psi[:m])}  # (5.37) chattering
        if with_vel:
            info["psi_v"] = psi[m:]
        return replace(s, x=x, P=P, e_post=e_post[:m], e_vel=e_post[m:] if with_vel else np.zeros(m),
                       z_prev=z_a, tau=0.0, F=None, info=info)


    # ---- batched forms (the same equations over T tracks at once; the per-track update is their reference,
    # tests/test_trackers_svsf.py checks them equal to 1e-12)
    def predict_many(self, states: list[FilterState], dt: float) -> list[FilterState]:
        """`predict` of T tracks at once (a linear motion model; otherwise the per-track loop)."""
        dt = float(dt)
        if not math.isfinite(dt) or dt < 0:
            raise ValueError(f"predict needs a finite dt >= 0, got {dt}")
        if not states or not self.motion.linear:
            return [self.predict(s, dt) for s in states]
        return self.predict_rows(states, rows_of(states, "x"), rows_of(states, "P"), rows_of(states, "e_post"), dt)

    def predict_rows(self, states: list[FilterState], X: np.ndarray, P: np.ndarray, e_post: np.ndarray,
                     dt: float) -> list[FilterState]:
        """`predict_many` of T states whose x, P, e_post are the rows X (T, n), P (T, n, n), e_post (T, m) (the IMM's
        mixed initial conditions; the states give the other fields), for a linear motion model and dt >= 0 (checked
        by the caller): a StateRows carrying the predicted x, P and e_post."""
        states = [promote_state(SVSFState, s) for s in states]
        A, Q = self.motion.transition(dt), self.motion.process_noise(dt)
        X = X @ A.T  # (2.7) x = A x
        P = A @ P @ A.T + Q  # (2.8) P = A P A^T + Q
        P = 0.5 * (P + np.swapaxes(P, 1, 2))
        check_covariance(P, "predicted covariance P")
        freeze(X, P, A, e_post)
        return StateRows([svsf_state(x, p, e, A, {}, s.z_prev, s.tau + dt, s.e_vel) if type(s) is SVSFState
                          else derive_frozen(s, x=x, P=p, e_post=e, F=A, info={}, tau=s.tau + dt)
                          for s, x, p, e in zip(states, X, P, e_post)], X, P, e_post)

    def update_many(self, preds: list[FilterState], nu: np.ndarray, W: np.ndarray,
                    w0: np.ndarray, R: np.ndarray | None = None) -> list[FilterState]:
        """`update` of T tracks at once: nu (T, M, m), W (T, M), w0 (T,), R (M, m, m) or None; artificial velocity
        measurements (either `artificial_pda`), "mse" covariance and a linear measurement, else the per-track loop."""
        if self.unmeasured != "artificial" or self.covariance != "mse" or not self.measurement.linear:
            return ModelFilter.update_many(self, preds, nu, W, w0, R)
        out = [after_miss(s, self.memory_after_miss) for s in preds]  # the active tracks are replaced below
        T = len(preds)
        active = np.flatnonzero((w0 < 1.0) & (W > 0.0).any(axis=1)) if T else np.zeros(0, dtype=np.int64)
        if active.size == 0:
            return out
        m = self.measurement.ndim
        nua, Wa, b0 = batch_weights(nu, W, w0, active)  # (A, M, m), (A, M), (A,)
        ss = [promote_state(SVSFState, preds[t]) for t in active]
        X = rows_of(preds, "x", active)  # the states' fields stacked (the rows a StateRows carries)
        P = rows_of(preds, "P", active)
        e_post = rows_of(preds, "e_post", active)
        e_vel = np.array([s.e_vel if s.e_vel is not None else np.zeros(m) for s in ss])
        z_prev = np.array([s.z_prev if s.z_prev is not None else np.full(m, np.nan) for s in ss])
        tau = np.array([s.tau for s in ss])
        H0 = self.measurement.matrix(self.motion)
        R0 = self.measurement.R if R is None else weighted_R(R, Wa)  # (m, m) or (A, m, m) [D]
        Hv = np.zeros((m, X.shape[1]))
        Hv[range(m), self.motion.velocity] = 1.0
        z_a, vel, t_v, nu_c = _artificial_many(X, z_prev, tau, nua, Wa, H0, Hv, self.artificial_pda)
        e_prev = np.concatenate([e_post, e_vel], axis=1)
        psi_p = np.array(self.psi, dtype=np.float64)
        psi_v = (np.broadcast_to(float(self.psi_v), (len(ss), m)) if self.psi_v is not None
                 else 3.0 * np.sqrt(2.0 * np.diagonal(R0, axis1=-2, axis2=-1) / t_v[:, None] ** 2))  # §2.3 [D] 3 sigma
        psi = np.concatenate([np.broadcast_to(psi_p, (len(ss), m)), psi_v], axis=1)
        E = np.abs(nu_c) + self.gamma * np.abs(e_prev)  # (2.10) |e_{k|k-1}| + gamma |e_{k-1|k-1}|
        g = svsf_gain_factor(E, nu_c, psi)
        g_p = svsf_gain_factor(E[:, :m], nu_c[:, :m], psi_p)  # a first update (no z_prev): the position rows
        H_bar = np.vstack([H0, Hv])
        K_v = np.linalg.pinv(H_bar)[None] * g[:, None, :]  # (2.30) K = H^+ diag(E o sat(e/psi)) diag(e)^-1
        K_p = np.linalg.pinv(H0)[None] * g_p[:, None, :]
        dx = np.where(vel[:, None], np.einsum("anm,am->an", K_v, nu_c),
                      np.einsum("anm,am->an", K_p, nu_c[:, :m]))
        Xn = X + dx  # (2.29)
        if not np.isfinite(Xn).all():
            raise FilterError("SVSF updated state x is not finite")
        Pn = estimate_mse_many(P, H0, R0, X, Xn, nua, Wa, b0)  # [R] MSE about x given the innovations
        check_covariance(Pn, "SVSF updated covariance P")
        post_v = nu_c - np.einsum("in,an->ai", H_bar, np.einsum("anm,am->an", K_v, nu_c))  # (2.34)/(3.65)
        post_p = nu_c[:, :m] - np.einsum("in,an->ai", H0, np.einsum("anm,am->an", K_p, nu_c[:, :m]))
        chatter_v = np.maximum(0.0, np.abs(nu_c[:, :m]) - psi[:, :m])  # (5.37) chattering, with velocity rows
        chatter_p = np.maximum(0.0, np.abs(nu_c[:, :m]) - psi_p)  # (5.37) chattering, position rows only
        ep = np.where(vel[:, None], post_v[:, :m], post_p)  # (A, m) memories: e_post, and e_vel (0 without velocity)
        ev = np.where(vel[:, None], post_v[:, m:], 0.0)
        freeze(Xn, Pn, ep, ev, z_a)
        for i, (t, v) in enumerate(zip(active, vel.tolist())):
            if v:
                psi_i = psi[i]
                info = {"psi_z": psi_i[:m], "chatter": chatter_v[i], "psi_v": psi_i[m:]}
            else:
                info = {"psi_z": psi_p.copy(), "chatter": chatter_p[i]}
            out[t] = (svsf_state(Xn[i], Pn[i], ep[i], None, info, z_a[i], 0.0, ev[i]) if type(ss[i]) is SVSFState
                      else derive_frozen(ss[i], x=Xn[i], P=Pn[i], e_post=ep[i], e_vel=ev[i], z_prev=z_a[i], tau=0.0,
                                         F=None, info=info))
        return updated_rows(preds, out, active, Xn, Pn, ep, reset=self.memory_after_miss == "reset")


def _artificial_many(X, z_prev, tau, nua, Wa, H0, Hv, artificial_pda: str):
    """(z^a (A, m), with-velocity flags (A,), tau or 1 (A,), e_{z,k|k-1} (A, 2m)) of `SVSF.update` for A tracks:
    X (A, n), z_prev (A, m) (NaN before a first update), tau (A,), nua (A, M, m), Wa (A, M), H0 (m, n), Hv (m, n)."""
    z_hat = X @ H0.T
    z_a = z_hat + np.einsum("aj,ajm->am", Wa, nua)  # (2.32) projected measurement
    vel = (tau > 0.0) & np.isfinite(z_prev).all(axis=1)
    t_v = np.where(vel, tau, 1.0)
    zp = np.where(vel[:, None], z_prev, 0.0)
    nu_v = (z_hat[:, None, :] + nua - zp[:, None, :]) / t_v[:, None, None] - (X @ Hv.T)[:, None, :]  # [17]
    nu_bar = np.concatenate([nua, np.where((Wa > 0.0)[..., None], nu_v, 0.0)], axis=2)  # (A, M, 2m)
    nu_c = np.einsum("aj,ajm->am", Wa, nu_bar)  # (2.27) e_{z,k|k-1} := combined innovation
    if artificial_pda == "combined":  # (2.32) one artificial measurement from z^a [D]
        nu_c[:, H0.shape[0]:] = (z_a - zp) / t_v[:, None] - X @ Hv.T
    return z_a, vel, t_v, nu_c


def estimate_mse_many(P, H, R, x_pred, x, nu, W, w0) -> np.ndarray:
    """`estimate_mse` of A tracks at once: P (A, n, n), x_pred and x (A, n), nu (A, M, m), W (A, M), w0 (A,)."""
    S = H @ P @ H.T + R
    S = 0.5 * (S + np.swapaxes(S, 1, 2))
    K_kf = np.swapaxes(np.linalg.solve(S, H @ P), 1, 2)  # (4.73): the Kalman gain
    P_kf = P - K_kf @ S @ np.swapaxes(K_kf, 1, 2)
    P_kf = 0.5 * (P_kf + np.swapaxes(P_kf, 1, 2))
    d0 = x - x_pred
    m = nu.shape[2]
    KNu = (np.einsum("ajm,anm->ajn", nu, K_kf) if m > 2  # (A, M, n) K_kf nu_j; for m <= 2 its products summed
           else sum_in_order([nu[:, :, None, i] * K_kf[:, None, :, i] for i in range(m)]))  # as einsum does
    D = d0[:, None, :] - KNu  # (A, M, n)
    out = (w0[:, None, None] * (P + np.einsum("ai,ak->aik", d0, d0)) + (1.0 - w0)[:, None, None] * P_kf
           + weighted_outer(W, D))
    return 0.5 * (out + np.swapaxes(out, 1, 2))

# ------------------------------------------------------------------------------- generalised (CM-) SVSF
@dataclass(frozen=True)
class GeneralisedSVSF(ModelFilter):
    """Generalised / covariance-modified SVSF, "CM-SVSF" (thesis ch. 3 §3.5.1; ch. 4 §4.4, (4.24)-(4.37)).

    Measured partition:   K_u = H1^-1 diag(E_z o sat(e, psi_z)) diag(e)^-1,  E_z = |e| + gamma |e_{k-1|k-1}|
                          (4.29)-(4.30)
    Unmeasured partition: K_l = diag(E_y o sat(e_y, psi_y)) diag(e_y)^-1 Phi22 Phi12^+,  e_y = Phi22 Phi12^+ e,
                          E_y = |e_y| + gamma_y |Phi12^+ e|  (4.33)-(4.34)
    Covariance:           P* = P - K H P - P H^T K^T + K S K^T,  K = [K_u; K_l]  (4.37), covariance = "joseph";
                          default "mse": `estimate_mse` (module docstring)
    with e = e_{z,k|k-1} the combined innovation (3.54) and Phi from the transition Jacobian of the last
    predict. psi_z (m,) [m] and psi_y are fixed layers; psi_y None uses 3 sqrt(diag(M R M^T)) each scan,
    M = Phi22 Phi12^+ (the 3-sigma width of e_y from measurement noise alone; 3 sigma_w / dt for NCV).
    ey_memory: the gamma_y term of E_y with the a priori error (thesis (3.38)/(4.34), default) or
    with the previous a posteriori error ("a_posteriori"). memory_after_miss: "keep" (default) or "reset" the
    memory e_{z,k-1|k-1} after a scan without update (module docstring).

    Needs Phi12 invertible, i.e. n = 2m (NCV). For the 5-D CT model Phi12 is 2 x 3 and the pseudo-inverse
    map Phi22 Phi12^+ puts most of a position error into the turn rate (the minimum-norm solution in mixed
    units); the saturated lower gain then corrects omega dead-beat from one scan and the filter diverged in
    test (velocity errors of 1e7 m/s after 50 scans), so CT is refused; use the GVBL-SVSF for CT."""

    motion: object
    measurement: object
    gamma: float = 0.1
    gamma_y: float = 0.1
    psi_z: tuple[float, ...] = (1.0, 1.0)
    psi_y: float | None = None
    ey_memory: str = "a_priori"
    covariance: str = "mse"
    memory_after_miss: str = "keep"

    def __post_init__(self) -> None:
        m = self.measurement.ndim
        check_memory_after_miss("GeneralisedSVSF", self.memory_after_miss)
        if self.covariance not in ("mse", "joseph"):
            raise ValueError(f"GeneralisedSVSF covariance must be mse|joseph, got {self.covariance!r}")
        if not (0.0 <= self.gamma < 1.0 and 0.0 <= self.gamma_y < 1.0):
            raise ValueError(f"GeneralisedSVSF gamma and gamma_y must be in [0, 1), got {self.gamma}, {self.gamma_y}")
        if len(self.psi_z) != m or not all(math.isfinite(p) and p > 0 for p in self.psi_z):
            raise ValueError(f"GeneralisedSVSF psi_z must be {m} finite widths > 0, got {self.psi_z}")
        if self.psi_y is not None and not (math.isfinite(self.psi_y) and self.psi_y > 0):
            raise ValueError(f"GeneralisedSVSF psi_y must be a finite width > 0 or None, got {self.psi_y}")
        if self.ey_memory not in EY_MEMORY:
            raise ValueError(f"GeneralisedSVSF ey_memory must be one of {EY_MEMORY}, got {self.ey_memory!r}")
        if self.motion.ndim != 2 * m:
            raise ValueError(f"GeneralisedSVSF needs as many unmeasured as measured states (Phi12 invertible, "
                             f"(3.36)-(3.37)); {type(self.motion).__name__} has {self.motion.ndim} states")

    def layer(self, s_pred: FilterState) -> np.ndarray:
        """The fixed measured-partition layer psi_z (m,) [m]."""
        return np.array(self.psi_z, dtype=np.float64)

    layers_many = SVSF.layers_many  # the fixed psi_z in every row

    def update(self, s_pred: FilterState, nu: np.ndarray, beta: np.ndarray, beta0: float,
               R: np.ndarray | None = None) -> FilterState:
        """PDA-form generalised SVSF update (see class docstring); nu (M, m), beta (M,), beta0; R (M, m, m): the
        detections' own covariances (their beta-weighted mean replaces the model's R, [D]) or None."""
        nu, beta, beta0 = check_weights(nu, beta, beta0, self.measurement.ndim)
        if nu.shape[0] == 0 or beta0 == 1.0:
            return after_miss(s_pred, self.memory_after_miss)  # (4.16) with beta0 = 1: no update
        H = self.measurement_jacobian(s_pred)
        R = self.measurement.R if R is None else weighted_R(R, beta[None])[0]
        part = Partition.of(H)
        M, Phi12_pinv = part.maps(s_pred.F)
        S = symmetrise(H @ s_pred.P @ H.T + R)  # (4.37): S = H1 P11 H1^T + R
        cholesky(S, "innovation covariance S")
        e = combined_innovation(nu, beta)  # (3.54) e_{z,k|k-1} := combined innovation
        psi_z = np.array(self.psi_z, dtype=np.float64)
        E_z = np.abs(e) + self.gamma * np.abs(s_pred.e_post)  # (4.30)
        K_u = np.linalg.solve(part.H1, np.diag(svsf_gain_factor(E_z, e, psi_z)))  # (4.29)
        e_y, E_y = lower_error(M, Phi12_pinv, e, s_pred.e_post, self.gamma_y, self.ey_memory)
        psi_y = (np.full(e_y.size, self.psi_y) if self.psi_y is not None
                 else 3.0 * np.sqrt(np.maximum(np.diag(M @ R @ M.T), 1e-300)))  # [D] 3-sigma of e_y from R
        K_l = svsf_gain_factor(E_y, e_y, psi_y)[:, None] * M  # (4.33) diag(E_y o sat(e_y/psi_y)) diag(e_y)^-1 M
        K = part.assemble(K_u, K_l)
        x = s_pred.x + K @ e  # (4.35)
        P = (estimate_mse(s_pred.P, H, R, s_pred.x, x, nu, beta, beta0) if self.covariance == "mse"  # [R]
             else pda_covariance(s_pred.P, generalised_covariance(s_pred.P, K, H, S), K, nu, beta, beta0))  # (4.37)
        if not np.isfinite(x).all():
            raise FilterError("generalised SVSF updated state x is not finite")
        check_covariance(P, "generalised SVSF updated covariance P")
        info = {"psi_z": psi_z, "psi_y": psi_y, "chatter": np.maximum(0.0, np.abs(e) - psi_z)}  # (5.37)
        return replace(s_pred, x=x, P=P, e_post=e - H @ (K @ e), F=None, info=info)  # (3.65)

    def update_many(self, preds: list[FilterState], nu: np.ndarray, W: np.ndarray,
                    w0: np.ndarray, R: np.ndarray | None = None) -> list[FilterState]:
        """`update` of T tracks at once: nu (T, M, m), W (T, M), w0 (T,), R (M, m, m) or None, with a linear
        measurement and the transition Jacobians of the last predict (else the per-track loop, the reference it is
        tested against). The partition maps of one Jacobian shared by every track (NCV) are computed once."""
        out = [after_miss(s, self.memory_after_miss) for s in preds]  # the active tracks are replaced below
        T = len(preds)
        active = np.flatnonzero((w0 < 1.0) & (W > 0.0).any(axis=1)) if T else np.zeros(0, dtype=np.int64)
        if active.size == 0:
            return out
        ss = [preds[t] for t in active]
        if not self.measurement.linear or any(s.F is None for s in ss):
            return ModelFilter.update_many(self, preds, nu, W, w0, R)
        nua, Wa, b0 = batch_weights(nu, W, w0, active)  # (A, M, m), (A, M), (A,)
        H = self.measurement.matrix(self.motion)
        R = self.measurement.R if R is None else weighted_R(R, Wa)  # (m, m) or (A, m, m) [D]
        part = Partition.of(H)
        Mm, Phi12_pinv, _ = maps_many(part, [s.F for s in ss])
        X = rows_of(preds, "x", active)  # the states' fields stacked (the rows a StateRows carries)
        P = rows_of(preds, "P", active)
        e_post = rows_of(preds, "e_post", active)
        A_, m = len(ss), H.shape[0]
        S = H @ P @ H.T + R
        S = 0.5 * (S + np.swapaxes(S, 1, 2))  # (4.37): S = H1 P11 H1^T + R
        try:
            np.linalg.cholesky(S)
        except np.linalg.LinAlgError:
            raise FilterError("innovation covariance S is not positive definite") from None
        e = np.einsum("aj,ajm->am", Wa, nua)  # (3.54) e_{z,k|k-1} := combined innovation
        psi_z = np.array(self.psi_z, dtype=np.float64)
        E_z = np.abs(e) + self.gamma * np.abs(e_post)  # (4.30)
        g_u = svsf_gain_factor(E_z, e, psi_z)
        K_u = np.linalg.solve(np.broadcast_to(part.H1, (A_, m, m)), g_u[:, :, None] * np.eye(m))  # (4.29)
        e_y = apply_rows(Mm, e)  # (3.37)
        mem = e if self.ey_memory == "a_priori" else e_post
        E_y = np.abs(e_y) + self.gamma_y * np.abs(apply_rows(Phi12_pinv, mem))  # (4.34) E_y
        if self.psi_y is not None:
            psi_y = np.full(e_y.shape, self.psi_y)
        else:  # [D] 3-sigma of e_y from R
            MRM = Mm @ R @ np.swapaxes(Mm, -1, -2)
            psi_y = np.broadcast_to(3.0 * np.sqrt(np.maximum(np.diagonal(MRM, axis1=-2, axis2=-1), 1e-300)),
                                    e_y.shape)
        Mb = np.broadcast_to(Mm, (A_,) + Mm.shape[-2:])
        K = np.zeros((A_, X.shape[1], m))
        K[:, part.u] = K_u
        K[:, part.l] = svsf_gain_factor(E_y, e_y, psi_y)[:, :, None] * Mb  # (4.33)
        Ke = np.einsum("anm,am->an", K, e)
        Xn = X + Ke  # (4.35)
        if self.covariance == "mse":
            Pn = estimate_mse_many(P, H, R, X, Xn, nua, Wa, b0)  # [R]
        else:
            KHP = K @ H @ P
            P_star = P - KHP - np.swapaxes(KHP, 1, 2) + K @ S @ np.swapaxes(K, 1, 2)  # (4.37)
            P_star = 0.5 * (P_star + np.swapaxes(P_star, 1, 2))
            spread = weighted_outer(Wa, nua) - np.einsum("ai,ak->aik", e, e)
            Pn = (b0[:, None, None] * P + (1.0 - b0)[:, None, None] * P_star
                  + K @ spread @ np.swapaxes(K, 1, 2))  # (4.16)
            Pn = 0.5 * (Pn + np.swapaxes(Pn, 1, 2))
        if not np.isfinite(Xn).all():
            raise FilterError("generalised SVSF updated state x is not finite")
        check_covariance(Pn, "generalised SVSF updated covariance P")
        post = e - Ke @ H.T  # (3.65)
        freeze(Xn, Pn, post)
        for i, t in enumerate(active):
            info = {"psi_z": psi_z.copy(), "psi_y": np.array(psi_y[i]),
                    "chatter": np.maximum(0.0, np.abs(e[i]) - psi_z)}  # (5.37)
            out[t] = derive_frozen(ss[i], x=Xn[i], P=Pn[i], e_post=post[i], F=None, info=info)
        return updated_rows(preds, out, active, Xn, Pn, post, reset=self.memory_after_miss == "reset")


# ------------------------------------------------------------------------------- registry parameters

GAMMA = (lambda v: 0.0 <= v < 1.0, "in [0, 1)")
MEMORY_AFTER_MISS_DOC = ("SVSF memory e_{z,k-1|k-1} of the gain after a scan without update (empty gate or "
                         "beta0 = 1), which the thesis leaves open: 'keep' (no update changes nothing, (4.16)) or "
                         "'reset' to 0 (the next gain starts without memory, as at birth)")


def noise_layer(R: np.ndarray, sigmas: float = 3.0) -> tuple[float, ...]:
    """Default fixed layer half widths sigmas * sqrt(R_jj) (m,) (thesis §2.3 [D]: about 3 sqrt(S_jj))."""
    return tuple(float(v) for v in sigmas * np.sqrt(np.diag(R)))


@dataclass(frozen=True)
class SVSFParams(ModelParams):
    gamma: float = param(0.1, "SVSF memory / convergence rate gamma (thesis ch. 2-5; 0.1 in ch. 4)", check=GAMMA)
    psi: float | None = param(None, "position boundary-layer half width [m]; None: 3 sigma_w (thesis §2.3 [D])",
                              check=POSITIVE)
    psi_v: float | None = param(None, "artificial-velocity layer half width [m/s]; None: 3 sqrt(2) sigma_w / dt",
                                check=POSITIVE)
    unmeasured: str = param("artificial", "m < n: artificial velocity measurements of [17] (thesis §4.5.1) or "
                            "the literal H^+ of (2.30), which never corrects velocities",
                            choices=("artificial", "pinv"))
    covariance: str = param("mse", "mse: the mean-square error about the SVSF estimate given the innovations "
                            "(consistent; the KF's P when e = 0); joseph: (2.12)/(2.31) as printed, which grows "
                            "with Q when the in-layer gain is small; short: (I - K H) P of (2.54)/(2.89)",
                            choices=COVARIANCES)
    artificial_pda: str = param("per_measurement", "artificial velocity under PDA, which the thesis leaves open: "
                                "'per_measurement', one per validated measurement combined with the weights "
                                "beta (2.27) (the velocity correction carries 1 - beta0), or 'combined', one from "
                                "the projected measurement z^a = z_hat + sum beta_i nu_i (2.32), (3.63) "
                                "differenced, whose PDA spread term (4.17) is the position spread mapped by "
                                "[I; I/tau]; equal when beta0 = 0", choices=ARTIFICIAL_PDA)
    memory_after_miss: str = param("keep", MEMORY_AFTER_MISS_DOC, choices=MEMORY_AFTER_MISS)


@dataclass(frozen=True)
class GCSVSFParams(ModelParams):
    gamma: float = param(0.1, "memory gamma_z of the measured partition (4.30)", check=GAMMA)
    gamma_y: float | None = param(None, "memory gamma_y of the unmeasured partition (4.34); None: gamma",
                                  check=GAMMA)
    psi_z: float | None = param(None, "measured-partition layer half width [m]; None: 3 sigma_w [D]", check=POSITIVE)
    psi_y: float | None = param(None, "unmeasured-partition layer half width (velocity units); None: "
                                "3 sqrt(diag(M R M^T)) per scan, M = Phi22 Phi12^+ (3 sigma_w / dt for NCV) [D]",
                                check=POSITIVE)
    ey_memory: str = param("a_priori", "gamma_y term of E_y: a priori error (thesis (4.34)) or the previous "
                           "a posteriori error (Habibi's original)", choices=EY_MEMORY)
    covariance: str = param("mse", "mse: the mean-square error about the estimate given the innovations; "
                            "joseph: the generalised covariance (4.37) as printed", choices=("mse", "joseph"))
    memory_after_miss: str = param("keep", MEMORY_AFTER_MISS_DOC, choices=MEMORY_AFTER_MISS)


def build_svsf(p: SVSFParams) -> SVSF:
    if p.motion != "cv":
        raise ParamError("motion", f"{p.motion!r}: the standard SVSF corrects only measured and differenced "
                         "states (the turn rate never); use 'cv', or gc-svsf / gvbl-svsf for 'ct'")
    meas = p.measurement_model()
    psi = noise_layer(meas.R) if p.psi is None else (p.psi,) * meas.ndim
    return SVSF(p.motion_model(), meas, gamma=p.gamma, psi=psi, psi_v=p.psi_v, unmeasured=p.unmeasured,
                covariance=p.covariance, artificial_pda=p.artificial_pda, memory_after_miss=p.memory_after_miss)


def build_gc_svsf(p: GCSVSFParams) -> GeneralisedSVSF:
    if p.motion != "cv":
        raise ParamError("motion", f"{p.motion!r}: the generalised SVSF needs Phi12 invertible (n = 2m, 'cv'); "
                         "its pseudo-inverse form diverges for 'ct' (use gvbl-svsf)")
    meas = p.measurement_model()
    psi_z = noise_layer(meas.R) if p.psi_z is None else (p.psi_z,) * meas.ndim
    return GeneralisedSVSF(p.motion_model(), meas, gamma=p.gamma, gamma_y=p.gamma if p.gamma_y is None else p.gamma_y,
                           psi_z=psi_z, psi_y=p.psi_y, ey_memory=p.ey_memory, covariance=p.covariance,
                           memory_after_miss=p.memory_after_miss)
