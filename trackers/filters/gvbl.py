"""Generalised variable boundary layer SVSF, GVBL-SVSF (thesis ch. 4 §4.5.1, (4.39)-(4.73); restated
in ch. 5 (5.12)-(5.18)), in PDA form (thesis §4.5.2).

One update, with e = e_{z,k|k-1} the combined innovation (2.27) and S = H1 P11 H1^T + R:
1. E_z = |e| + gamma |e_{z,k-1|k-1}| (4.30); e_y = Phi22 Phi12^+ e, E_y = |e_y| + gamma_y |Phi12^+ e| (4.34).
2. Optimal layers Psi_z = (E_z^-1 H1 P11 H1^T S^-1)^-1 = S (H1 P11 H1^T)^-1 diag(E_z)          (4.61)
                   Psi_y = (E_y^-1 P21 H1^T S^-1 (Phi22 Phi12^-1)^-1)^-1 = X^+ diag(E_y)          (4.68)
   with X = P21 H1^T S^-1 (Phi22 Phi12^+)^+; the pseudo-inverses equal the inverses for NCV and keep (4.68)
   defined for the 5-D CT model and for a singular P21.
3. Switch (thesis §4.5.1 step 2: "its diagonal elements are compared with psi_max; if larger, the corrective
   gain is calculated by (4.39) and (4.40), if smaller, from (4.71) and (4.72)"):
   optimal regime: K = P H^T S^-1, the Kalman gain (4.71)-(4.73);
   robust regime:  K_u = H1^-1 diag(E_z o sat(e, psi_max)) diag(e)^-1, i.e. (4.39) with Psi_z = psi_max I, and
                   K_l by `robust_lower` (below).
4. x = x_pred + K e (4.35); P* by the generalised covariance (4.37) then the PDA combination (4.16)-(4.17);
   e_{z,k|k} = (I - H K) e (3.65).

Implementation decisions the thesis leaves open (§4.5.1 step 2 names the switch but not its rule), all
parameters of `GVBLSVSF`:
* robust-branch layer: Psi = psi_max I (with the optimal layer inside sat the gain is the Kalman gain again:
  diag(Psi_z)_j = (1 + R_jj (P11^-1)_jj) E_z,j > |e_j| for diagonal R, so the innovation is always inside it).
* `switch`: which diagonals trigger the robust regime, compared in absolute value (Psi_y can be negative):
  "z_any" (default: any |Psi_z,jj| > psi_max, both partitions switch), "all_any" (any |Psi_z,jj| or
  |Psi_y,jj|), "per_partition" (each partition by its own layer). With the ch. 4 numbers |Psi_y| is about
  60 |e_j| (Ts = 0.5 s), so any rule that includes Psi_y is robust for almost every scan; "z_any" keeps the
  filter at the KF in steady state, which is what thesis Fig. 4.9 shows.
* `robust_lower`: "optimal" (default) keeps K_l = P21 H1^T S^-1 (4.72) in the robust regime, i.e. only the
  measured partition saturates; "psi_max" uses (4.40) with Psi_y = psi_max I, whose velocity gain reaches
  (1 + gamma_y)/Ts (a 5 m innovation gives a 5.5 m/s velocity kick at Ts = 0.5 s, against about 0.4 m/s for
  the KF) and was found to diverge even without clutter. Both are tested.
* How often it switches: with psi_max = 20 m and the ch. 4 parameters the robust regime engages when a
  position innovation exceeds about 4-5 m (the NCV steady state: |Psi_z| is about 4.2 |e_j|); `info["regime"]` records it per scan
  (1 robust, 0 optimal), so a run's switching rate is the mean of that column. Measured on the thesis §4.6.1
  cars (testbed.reproduce.thesis.synthetic, tests/test_trackers_svsf.py): 21-24 % of the scans with clutter 1e-4 /m^2, and
  never with the printed 1e-2 /m^2 (the PDA-shrunk combined innovation and the clutter-inflated P keep
  |Psi_z| below psi_max, so the filter is exactly the KF); "all_any" is robust on 99 % of the scans.
  With psi_max = None (no limit) the filter is the Kalman filter exactly.

Boundary layer reported to association (`layer`, read by the APDA as psi_{z,k+1} of (5.37)), `apda_layer`:
* "previous_capped" (default): min(|diag Psi_z| of the previous update, psi_max), or psi_max before the first
  update (None when psi_max is None): the reading in which psi_{z,k+1} is a GVBL layer (5.16), the last one
  known before association;
* "psi_max": psi_max on every scan (None when psi_max is None): the reading in which psi_{z,k+1} is the layer
  of the current scan, min(Psi_z, psi_max), whose chattering is non-zero only where psi_max binds, so that
  C = max(0, |nu| - psi_max) and det Psi = psi_max^m in (5.54).
The layer of the current scan itself cannot be used: it depends on the combined innovation, which needs the
association weights, and with the unsaturated optimal layer the chattering max(0, |nu| - Psi_z) of (5.37) would
be identically zero (diag Psi_z > |e| for diagonal R).

After a scan without update the memory e_{z,k-1|k-1} is kept or reset (`memory_after_miss`, as the SVSFs of
`svsf.py`); the reported layer is kept either way.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from roadtrack.trackers.errors import FilterError
from roadtrack.trackers.filters.base import (ModelFilter, batch_weights, check_covariance, check_weights, cholesky,
                                   combined_innovation, pda_covariance, symmetrise, weighted_R, weighted_outer)
from roadtrack.trackers.filters.svsf import (EY_MEMORY, GAMMA, MEMORY_AFTER_MISS, MEMORY_AFTER_MISS_DOC, Partition,
                                   after_miss, apply_rows, check_memory_after_miss, generalised_covariance,
                                   lower_error, maps_many, promote_state, svsf_gain_factor)
from roadtrack.trackers.filters.params import ModelParams
from roadtrack.trackers.params import POSITIVE, ParamError, param
from roadtrack.trackers.state import FilterState, derive_frozen, freeze, rows_of, updated_rows

SWITCH_RULES = ("z_any", "all_any", "per_partition")
ROBUST_LOWER = ("optimal", "psi_max")
APDA_LAYERS = ("previous_capped", "psi_max")


@dataclass(frozen=True, eq=False)
class GVBLState(FilterState):
    """FilterState of the GVBL-SVSF. psi_layer (m,) [m]: min(|diag Psi_z|, psi_max) of the last update,
    the layer `layer` reports for the next scan (None before the first update)."""

    psi_layer: np.ndarray | None = None

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.psi_layer is not None:
            a = np.array(self.psi_layer, dtype=np.float64)
            a.setflags(write=False)
            object.__setattr__(self, "psi_layer", a)


def optimal_layers(P: np.ndarray, S: np.ndarray, part: Partition, M: np.ndarray, E_z: np.ndarray,
                   E_y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(Psi_z (m, m), Psi_y (n-m, n-m)): the GVBL optimal layers for the prior covariance P (n, n),
    S (m, m), the partition, M = Phi22 Phi12^+ (n-m, m) and the error vectors E_z (m,), E_y (n-m,)."""
    H1, u, l = part.H1, part.u, part.l
    A = H1 @ P[np.ix_(u, u)] @ H1.T
    Psi_z = S @ np.linalg.solve(A, np.diag(E_z))  # (4.61) Psi_z = (E_z^-1 H1 P11 H1^T S^-1)^-1
    X = P[np.ix_(l, u)] @ H1.T @ np.linalg.solve(S, np.linalg.pinv(M))  # P21 H1^T S^-1 (Phi22 Phi12^-1)^-1
    Psi_y = np.linalg.pinv(X) @ np.diag(E_y)  # (4.68) Psi_y = (E_y^-1 X)^-1, pseudo-inverse [D]
    return Psi_z, Psi_y


def gvbl_state(x: np.ndarray, P: np.ndarray, e_post: np.ndarray, F: np.ndarray | None, info: dict,
               psi_layer: np.ndarray | None) -> GVBLState:
    """GVBLState of read-only arrays without __init__, its fields set one by one in their order (as
    state.frozen_state: half of derive_frozen's cost; the batched predict and update make T per scan)."""
    new = object.__new__(GVBLState)
    d = new.__dict__
    d["x"], d["P"], d["e_post"], d["F"], d["info"], d["psi_layer"] = x, P, e_post, F, info, psi_layer
    return new


@dataclass(frozen=True)
class GVBLSVSF(ModelFilter):
    """GVBL-SVSF (see module docstring). gamma, gamma_y in [0, 1) (thesis ch. 4: 0.1); psi_max [m] saturation
    limit of the optimal layer (thesis ch. 4: 20; math.inf = never robust = the KF); switch, robust_lower,
    ey_memory, apda_layer, memory_after_miss: the open choices of the module docstring. Works for NCV and,
    with robust_lower = "optimal" (the unmeasured rows keep the EKF gain), for the 5-D CT model (Phi12^+ only
    enters E_y and Psi_y)."""

    motion: object
    measurement: object
    gamma: float = 0.1
    gamma_y: float = 0.1
    psi_max: float = 20.0
    switch: str = "z_any"
    robust_lower: str = "optimal"
    ey_memory: str = "a_priori"
    apda_layer: str = "previous_capped"
    memory_after_miss: str = "keep"

    def __post_init__(self) -> None:
        check_memory_after_miss("GVBLSVSF", self.memory_after_miss)
        if self.apda_layer not in APDA_LAYERS:
            raise ValueError(f"GVBLSVSF apda_layer must be one of {APDA_LAYERS}, got {self.apda_layer!r}")
        if not (0.0 <= self.gamma < 1.0 and 0.0 <= self.gamma_y < 1.0):
            raise ValueError(f"GVBLSVSF gamma and gamma_y must be in [0, 1), got {self.gamma}, {self.gamma_y}")
        if math.isnan(self.psi_max) or self.psi_max <= 0:
            raise ValueError(f"GVBLSVSF psi_max must be > 0 (math.inf for no limit), got {self.psi_max}")
        if self.robust_lower == "psi_max" and self.motion.ndim != 2 * self.measurement.ndim:
            raise ValueError("GVBLSVSF robust_lower='psi_max' needs Phi12 invertible (n = 2m, NCV); use 'optimal'")
        if self.switch not in SWITCH_RULES or self.robust_lower not in ROBUST_LOWER or self.ey_memory not in EY_MEMORY:
            raise ValueError(f"GVBLSVSF switch must be one of {SWITCH_RULES}, robust_lower one of {ROBUST_LOWER}, "
                             f"ey_memory one of {EY_MEMORY}; got {self.switch!r}, {self.robust_lower!r}, "
                             f"{self.ey_memory!r}")

    def initial_state(self, x0: np.ndarray, P0: np.ndarray) -> GVBLState:
        return promote_state(GVBLState, super().initial_state(x0, P0))

    def layer(self, s_pred: FilterState) -> np.ndarray | None:
        """psi_{z,k+1} of (5.37) (m,) [m] for `apda_layer` (module docstring): "previous_capped": min(previous
        |diag Psi_z|, psi_max), psi_max before the first update; "psi_max": psi_max; None if unknown."""
        prev = getattr(s_pred, "psi_layer", None)
        if prev is not None and self.apda_layer == "previous_capped":  # (5.37) psi_{z,k+1}: the last GVBL layer [D]
            return np.array(prev)
        if math.isinf(self.psi_max):
            return None
        return np.full(self.measurement.ndim, self.psi_max)  # (5.37) psi_max: first scan, or apda_layer "psi_max"

    def layers_many(self, preds: list[FilterState], m: int) -> np.ndarray:
        """`layer` of T predicted states at once (T, m) [m], NaN rows where it is None."""
        out = np.full((len(preds), m), np.nan)
        if not math.isinf(self.psi_max):
            out[:] = self.psi_max  # (5.37) psi_max: first scan, or apda_layer "psi_max"
        if self.apda_layer == "previous_capped":  # (5.37) psi_{z,k+1}: the last GVBL layer [D]
            for t, s in enumerate(preds):
                prev = getattr(s, "psi_layer", None)
                if prev is not None:
                    out[t] = prev
        return out

    def update(self, s_pred: FilterState, nu: np.ndarray, beta: np.ndarray, beta0: float,
               R: np.ndarray | None = None) -> FilterState:
        """PDA-form GVBL-SVSF update; nu (M, m), beta (M,), beta0 (see module docstring); R (M, m, m): the
        detections' own covariances (their beta-weighted mean replaces the model's R, [D]) or None."""
        nu, beta, beta0 = check_weights(nu, beta, beta0, self.measurement.ndim)
        if nu.shape[0] == 0 or beta0 == 1.0:
            return after_miss(s_pred, self.memory_after_miss)  # (4.16) with beta0 = 1: no update
        s = promote_state(GVBLState, s_pred)
        H, P = self.measurement_jacobian(s), s.P
        R = self.measurement.R if R is None else weighted_R(R, beta[None])[0]
        part = Partition.of(H)
        M, Phi12_pinv = part.maps(s.F)
        S = symmetrise(H @ P @ H.T + R)  # (5.10) S = H1 P11 H1^T + R
        cholesky(S, "innovation covariance S")
        e = combined_innovation(nu, beta)  # (2.27)/(4.28) e_{z,k|k-1} := combined innovation
        E_z = np.abs(e) + self.gamma * np.abs(s.e_post)  # (4.30)
        e_y, E_y = lower_error(M, Phi12_pinv, e, s.e_post, self.gamma_y, self.ey_memory)  # (4.34)
        Psi_z, Psi_y = optimal_layers(P, S, part, M, E_z, E_y)
        psi_z, psi_y = np.abs(np.diag(Psi_z)), np.abs(np.diag(Psi_y))
        trip_z, trip_y = bool(np.any(psi_z > self.psi_max)), bool(np.any(psi_y > self.psi_max))  # §4.5.1 step 2
        robust_u = trip_z or (self.switch == "all_any" and trip_y)
        robust_l = trip_y if self.switch == "per_partition" else robust_u
        K = np.linalg.solve(S, H @ P).T  # (4.73) K_GVBL = P H^T S^-1 (the Kalman gain)
        if robust_u:
            K_u = np.linalg.solve(part.H1, np.diag(svsf_gain_factor(E_z, e, np.full(e.size, self.psi_max))))  # (4.39)
            K[part.u] = K_u
        if robust_l and self.robust_lower == "psi_max":
            K[part.l] = svsf_gain_factor(E_y, e_y, np.full(e_y.size, self.psi_max))[:, None] * M  # (4.40)
        P_post = pda_covariance(P, generalised_covariance(P, K, H, S), K, nu, beta, beta0)  # (4.37), (4.16)-(4.17)
        x = s.x + K @ e  # (4.35)
        if not np.isfinite(x).all():
            raise FilterError("GVBL-SVSF updated state x is not finite")
        check_covariance(P_post, "GVBL-SVSF updated covariance P")
        layer = np.minimum(psi_z, self.psi_max)  # [D] effective layer min(Psi_z, psi_max): the unsaturated one never chatters
        info = {"psi_z": psi_z, "psi_y": psi_y, "regime": float(robust_u), "regime_y": float(robust_l),
                "chatter": np.maximum(0.0, np.abs(e) - layer)}  # (5.37) chattering against the effective layer
        return replace(s, x=x, P=P_post, e_post=e - H @ (K @ e), F=None, info=info, psi_layer=layer)  # (3.65)


    def update_many(self, preds: list[FilterState], nu: np.ndarray, W: np.ndarray,
                    w0: np.ndarray, R: np.ndarray | None = None) -> list[FilterState]:
        """`update` of T tracks at once: nu (T, M, m), W (T, M), w0 (T,), R (M, m, m) or None (the per-track update is the reference,
        tests/test_trackers_svsf.py checks them equal to 1e-12). A linear measurement, else the per-track loop;
        the partition maps of one transition Jacobian shared by every track (NCV) are computed once, those of
        per-track Jacobians (CT) per track."""
        out = [after_miss(s, self.memory_after_miss) for s in preds]  # the active tracks are replaced below
        T = len(preds)
        active = np.flatnonzero((w0 < 1.0) & (W > 0.0).any(axis=1)) if T else np.zeros(0, dtype=np.int64)
        if active.size == 0:
            return out
        ss = [promote_state(GVBLState, preds[t]) for t in active]
        if not self.measurement.linear or any(s.F is None for s in ss):
            return ModelFilter.update_many(self, preds, nu, W, w0, R)
        nua, Wa, b0 = batch_weights(nu, W, w0, active)  # (A, M, m), (A, M), (A,)
        H = self.measurement.matrix(self.motion)
        R = self.measurement.R if R is None else weighted_R(R, Wa)  # (m, m) or (A, m, m) [D]
        part = Partition.of(H)
        Mm, Phi12_pinv, M_pinv = maps_many(part, [s.F for s in ss])
        X = rows_of(preds, "x", active)  # the states' fields stacked (the rows a StateRows carries)
        P = rows_of(preds, "P", active)
        e_post = rows_of(preds, "e_post", active)
        S = H @ P @ H.T + R
        S = 0.5 * (S + np.swapaxes(S, 1, 2))  # (5.10) S = H1 P11 H1^T + R
        try:
            np.linalg.cholesky(S)
        except np.linalg.LinAlgError:
            raise FilterError("innovation covariance S is not positive definite") from None
        e = np.einsum("aj,ajm->am", Wa, nua)  # (2.27)/(4.28) e_{z,k|k-1} := combined innovation
        E_z = np.abs(e) + self.gamma * np.abs(e_post)  # (4.30)
        e_y = apply_rows(Mm, e)  # (3.37)
        mem = e if self.ey_memory == "a_priori" else e_post
        E_y = np.abs(e_y) + self.gamma_y * np.abs(apply_rows(Phi12_pinv, mem))  # (4.34) E_y
        u, l, H1 = part.u, part.l, part.H1
        psi_z, psi_y = _optimal_layer_diagonals(P, S, part, M_pinv, E_z, E_y)
        trip_z, trip_y = np.any(psi_z > self.psi_max, axis=1), np.any(psi_y > self.psi_max, axis=1)  # §4.5.1 step 2
        robust_u = trip_z | (trip_y if self.switch == "all_any" else False)
        robust_l = trip_y if self.switch == "per_partition" else robust_u
        K = np.swapaxes(np.linalg.solve(S, H @ P), 1, 2)  # (4.73) the Kalman gain, (A, n, m)
        if robust_u.any():
            g = svsf_gain_factor(E_z, e, np.full(e.shape, self.psi_max))
            K_u = np.linalg.solve(np.broadcast_to(H1, (len(ss),) + H1.shape), _diag(g))  # (4.39)
            K[np.ix_(robust_u, u)] = K_u[robust_u]
        if self.robust_lower == "psi_max" and robust_l.any():
            g_y = svsf_gain_factor(E_y, e_y, np.full(e_y.shape, self.psi_max))
            K[np.ix_(robust_l, l)] = (g_y[:, :, None] * (Mm[None] if Mm.ndim == 2 else Mm))[robust_l]  # (4.40)
        KHP = K @ H @ P
        P_star = P - KHP - np.swapaxes(KHP, 1, 2) + K @ S @ np.swapaxes(K, 1, 2)  # (4.37)
        P_star = 0.5 * (P_star + np.swapaxes(P_star, 1, 2))
        spread = weighted_outer(Wa, nua) - np.einsum("ai,ak->aik", e, e)
        Pn = b0[:, None, None] * P + (1.0 - b0)[:, None, None] * P_star + K @ spread @ np.swapaxes(K, 1, 2)  # (4.16)
        Pn = 0.5 * (Pn + np.swapaxes(Pn, 1, 2))
        Ke = np.einsum("anm,am->an", K, e)
        Xn = X + Ke  # (4.35)
        if not np.isfinite(Xn).all():
            raise FilterError("GVBL-SVSF updated state x is not finite")
        check_covariance(Pn, "GVBL-SVSF updated covariance P")
        post = e - Ke @ H.T  # (3.65)
        layer = np.minimum(psi_z, self.psi_max)  # [D] effective layer
        chatter = np.maximum(0.0, np.abs(e) - layer)  # (5.37) chattering beyond the layer, (A, m)
        freeze(Xn, Pn, post, layer)
        for i, (t, ru, rl) in enumerate(zip(active, robust_u.tolist(), robust_l.tolist())):
            info = {"psi_z": psi_z[i], "psi_y": psi_y[i], "regime": float(ru), "regime_y": float(rl),
                    "chatter": chatter[i]}
            out[t] = (gvbl_state(Xn[i], Pn[i], post[i], None, info, layer[i]) if type(ss[i]) is GVBLState
                      else derive_frozen(ss[i], x=Xn[i], P=Pn[i], e_post=post[i], F=None, info=info, psi_layer=layer[i]))
        return updated_rows(preds, out, active, Xn, Pn, post, reset=self.memory_after_miss == "reset")




def _optimal_layer_diagonals(P: np.ndarray, S: np.ndarray, part: Partition, M_pinv: np.ndarray, E_z: np.ndarray,
                             E_y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """|diag Psi_z| (A, m) and |diag Psi_y| (A, n-m) of `optimal_layers` for A tracks at once: P (A, n, n),
    S (A, m, m), M_pinv = (Phi22 Phi12^+)^+ (m, n-m) shared or (A, m, n-m) per track, E_z (A, m), E_y (A, n-m)."""
    u, l, H1 = part.u, part.l, part.H1
    A_ = H1 @ P[:, u][:, :, u] @ H1.T
    Psi_z = S @ np.linalg.solve(A_, _diag(E_z))  # (4.61) Psi_z = (E_z^-1 H1 P11 H1^T S^-1)^-1
    M_pinv = np.broadcast_to(M_pinv, (len(P),) + M_pinv.shape[-2:])
    X = P[:, l][:, :, u] @ H1.T @ np.linalg.solve(S, M_pinv)  # P21 H1^T S^-1 (Phi22 Phi12^-1)^-1
    Psi_y = np.linalg.pinv(X) @ _diag(E_y)  # (4.68), pseudo-inverse [D]
    return np.abs(np.diagonal(Psi_z, axis1=1, axis2=2)), np.abs(np.diagonal(Psi_y, axis1=1, axis2=2))


def _diag(v: np.ndarray) -> np.ndarray:
    """(A, k, k) diagonal matrices of the rows of v (A, k)."""
    out = np.zeros(v.shape + (v.shape[-1],))
    idx = np.arange(v.shape[-1])
    out[:, idx, idx] = v
    return out

# ------------------------------------------------------------------------------- registry parameters


@dataclass(frozen=True)
class GVBLParams(ModelParams):
    gamma: float = param(0.1, "memory gamma_z of the measured partition (thesis ch. 4: 0.1)", check=GAMMA)
    gamma_y: float | None = param(None, "memory gamma_y of the unmeasured partition; None: gamma", check=GAMMA)
    psi_max: float | None = param(20.0, "saturation limit of the optimal layer [m] (thesis ch. 4: 20); "
                                  "None: no limit, i.e. the Kalman filter", check=POSITIVE)
    switch: str = param("z_any", "layer diagonals that trigger the robust regime: measured partition only, "
                        "both, or each partition by its own ([D], thesis §4.5.1 names no rule)", choices=SWITCH_RULES)
    robust_lower: str = param("optimal", "robust regime, unmeasured partition: keep the optimal gain (4.72) or "
                              "use (4.40) with Psi_y = psi_max I (its velocity gain reaches (1 + gamma) / Ts and diverges)",
                              choices=ROBUST_LOWER)
    ey_memory: str = param("a_priori", "gamma_y term of E_y: a priori error (thesis (4.34)) or the previous "
                           "a posteriori error", choices=EY_MEMORY)
    apda_layer: str = param("previous_capped", "boundary layer psi_{z,k+1} reported to the APDA (5.37), which the "
                            "thesis leaves open: 'previous_capped', min(|diag Psi_z| of the previous update "
                            "(5.16), psi_max), or 'psi_max', the saturation limit on every scan (the current "
                            "layer min(Psi_z, psi_max), whose chattering is non-zero only where psi_max binds)",
                            choices=APDA_LAYERS)
    memory_after_miss: str = param("keep", MEMORY_AFTER_MISS_DOC, choices=MEMORY_AFTER_MISS)


def build_gvbl(p: GVBLParams) -> GVBLSVSF:
    if p.motion != "cv" and p.robust_lower == "psi_max":
        raise ParamError("robust_lower", "'psi_max' needs Phi12 invertible ('cv'); with 'ct' use 'optimal'")
    return GVBLSVSF(p.motion_model(), p.measurement_model(), gamma=p.gamma,
                    gamma_y=p.gamma if p.gamma_y is None else p.gamma_y,
                    psi_max=math.inf if p.psi_max is None else p.psi_max, switch=p.switch,
                    robust_lower=p.robust_lower, ey_memory=p.ey_memory, apda_layer=p.apda_layer,
                    memory_after_miss=p.memory_after_miss)
