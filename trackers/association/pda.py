"""Probabilistic data association, each track independently (thesis §4.2, (4.10)-(4.13))."""

from __future__ import annotations

import numpy as np

from roadtrack.trackers.association.logsum import logsumexp
from roadtrack.trackers.association.params import AssociationParams, check_inputs, track_pd


def pda_log_terms(log_lik: np.ndarray, gated: np.ndarray, pd: np.ndarray | float, pg: float,
                  clutter_density: float) -> tuple[np.ndarray, np.ndarray]:
    """(log(1 - P_D P_G) (T,), log L (T, M)) with L_i = P_D N_i / lambda on gated pairs, -inf elsewhere.
    pd: scalar or per-track (T,)."""
    pd = np.broadcast_to(np.asarray(pd, dtype=np.float64), (log_lik.shape[0],))
    with np.errstate(divide="ignore"):
        log_miss = np.log1p(-pd * pg)  # (4.10)-(4.13) miss term 1 - P_D P_G
        # (4.10)-(4.13) L_i = N P_D / lambda
        log_L = np.where(gated, np.log(pd)[:, None] + log_lik - np.log(clutter_density), -np.inf)
    return log_miss, log_L


def pda_log_denominator(log_lik: np.ndarray, gated: np.ndarray, pd: np.ndarray | float, pg: float,
                        clutter_density: float) -> np.ndarray:
    """log(1 - P_D P_G + sum_i L_i) (T,): the denominator of (4.13) and the score increment of §7.2."""
    log_miss, log_L = pda_log_terms(log_lik, gated, pd, pg, clutter_density)
    terms = np.concatenate([log_miss[:, None], log_L], axis=1)
    return logsumexp(terms, axis=1)  # which ignores the floating-point warnings of its -inf terms itself


def pda(log_lik: np.ndarray, gated: np.ndarray, p: AssociationParams,
        pd: np.ndarray | float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """PDA weights beta_i = L_i / D, beta_0 = (1 - P_D P_G) / D, D = 1 - P_D P_G + sum_i L_i, in log space.
    pd: per-track P_D (T,) or None for p.pd.

    A track for which no hypothesis has positive probability (P_D P_G = 1 and nothing gated) gets w0 = 1."""
    log_lik, gated = check_inputs(log_lik, gated)
    pdt = track_pd(p, log_lik.shape[0], pd)
    log_miss, log_L = pda_log_terms(log_lik, gated, pdt, p.pg, p.clutter_density)
    log_d = pda_log_denominator(log_lik, gated, pdt, p.pg, p.clutter_density)
    ok = np.isfinite(log_d)
    safe = np.where(ok, log_d, 0.0)
    W = np.where(ok[:, None], np.exp(log_L - safe[:, None]), 0.0)  # (4.10)-(4.13) beta_i = L_i / D
    w0 = np.where(ok, np.exp(log_miss - safe), 1.0)  # (4.10)-(4.13) beta_0 = (1 - P_D P_G) / D
    return W, w0
