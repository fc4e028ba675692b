"""Association parameters and shared input checks.

Every associator has the signature

    fn(log_lik (T, M), gated (T, M) bool, p: AssociationParams) -> (W (T, M), w0 (T,))

log_lik[t, j] = log N(z_j; z_hat_t, S_t) (only read where gated); W[t, j] is the probability that
measurement j is track t's, w0[t] that track t has none. Rows of [W, w0] sum to 1; W is 0 where not gated.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

OVERFLOW_MODES = ("k_best", "pda", "raise")


@dataclass(frozen=True)
class AssociationParams:
    """pd: detection probability; pg: gate probability (see `gating.gate_probability`);
    clutter_density: Poisson clutter spatial density lambda [m^-2];
    use_pg: JPDA (and GNN) in the P_D P_G form (thesis §4.4 note [R]) instead of the thesis form (no P_G);
    max_events: cap on the feasible joint events of one JPDA cluster (method "enumerate");
    on_overflow: what JPDA does with a cluster over its method's budget (max_events, or the "ehm" net's
    max_nodes): "k_best" (that cluster's marginals from its k best joint events, counted as a fallback),
    "pda" (per-track PDA for that cluster, counted, with a JPDAOverflowWarning) or "raise"
    (JPDAOverflowError)."""

    pd: float
    pg: float
    clutter_density: float
    use_pg: bool = False
    max_events: int = 50_000
    on_overflow: str = "k_best"

    def __post_init__(self) -> None:
        for name in ("pd", "pg", "clutter_density"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v):
                raise ValueError(f"AssociationParams.{name} must be a finite number, got {v!r}")
        if not (0.0 <= self.pd <= 1.0 and 0.0 < self.pg <= 1.0):
            raise ValueError(f"AssociationParams needs 0 < pd <= 1 and 0 < pg <= 1, got pd={self.pd}, pg={self.pg}")
        if self.clutter_density <= 0.0:
            raise ValueError(f"AssociationParams.clutter_density must be > 0, got {self.clutter_density}")
        if not isinstance(self.use_pg, bool):
            raise ValueError(f"AssociationParams.use_pg must be a bool, got {self.use_pg!r}")
        if isinstance(self.max_events, bool) or not isinstance(self.max_events, int) or self.max_events < 1:
            raise ValueError(f"AssociationParams.max_events must be a positive int, got {self.max_events!r}")
        if self.on_overflow not in OVERFLOW_MODES:
            raise ValueError(f"AssociationParams.on_overflow must be one of {list(OVERFLOW_MODES)}, "
                             f"got {self.on_overflow!r}")


def check_inputs(log_lik: np.ndarray, gated: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Validate (T, M) log-likelihoods and gate flags; return float64 / bool arrays."""
    log_lik = np.asarray(log_lik, dtype=np.float64)
    gated = np.asarray(gated)
    if log_lik.ndim != 2 or gated.shape != log_lik.shape:
        raise ValueError(f"association needs log_lik and gated of the same (T, M) shape, "
                         f"got {log_lik.shape}, {gated.shape}")
    if gated.dtype != np.bool_:
        raise ValueError(f"gated must be a bool array, got dtype {gated.dtype}")
    if not np.isfinite(log_lik[gated]).all():
        raise ValueError("log_lik is not finite at a gated (track, measurement) pair")
    return log_lik, gated


def track_pd(p: AssociationParams, T: int, pd: np.ndarray | float | None = None) -> np.ndarray:
    """Per-track detection probabilities (T,): `pd` if given (scalar or (T,), e.g. occlusion-aware), else p.pd."""
    a = np.asarray(p.pd if pd is None else pd, dtype=np.float64)
    out = a.copy() if a.shape == (T,) else np.broadcast_to(a, (T,)).copy()
    if not ((out >= 0.0) & (out <= 1.0)).all():
        raise ValueError(f"per-track detection probabilities must lie in [0, 1], got {out[(out < 0) | (out > 1)][:3]}")
    return out


def joint_event_terms(log_lik: np.ndarray, p: AssociationParams,
                      pd: np.ndarray | float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Log factors of a JPDA joint event (4.19): a (T, M) for 'measurement j is track t's', b (T,) for 'track t
    missed'. pd: per-track P_D (T,) or None for p.pd.

    log P(Theta) = sum_{assigned (t, j)} a[t, j] + sum_{missed t} b[t] + const.
    Thesis form: a = ln(P_D N / lambda), b = ln(1 - P_D). P_D P_G form: P_D -> P_D P_G and N -> N / P_G."""
    pdt = track_pd(p, log_lik.shape[0], pd)
    pdt = pdt * p.pg if p.use_pg else pdt
    log_n = log_lik - np.log(p.pg) if p.use_pg else log_lik
    with np.errstate(divide="ignore"):
        a = np.log(pdt)[:, None] + log_n - np.log(p.clutter_density)  # (4.19) lambda^-1 N P_D per assigned pair
        b = np.log1p(-pdt)  # (4.19) (1 - P_D) per undetected target (-inf if P_D = 1)
    return a, b
