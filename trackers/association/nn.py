"""Nearest neighbour: each track takes its most likely gated measurement (hard weight; tracks may share one)."""

from __future__ import annotations

import numpy as np

from roadtrack.trackers.association.params import AssociationParams, check_inputs


def nearest_neighbour(log_lik: np.ndarray, gated: np.ndarray, p: AssociationParams,
                      pd: np.ndarray | float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """W[t, argmax_j log_lik[t, j] over gated j] = 1, else w0[t] = 1.

    For one track, max log N(nu; 0, S) is min Mahalanobis distance, so this is the nearest measurement
    in the statistical sense. `p` and `pd` are unused (kept for the common signature)."""
    log_lik, gated = check_inputs(log_lik, gated)
    T, M = log_lik.shape
    W = np.zeros((T, M))
    has = gated.any(axis=1)
    if M:
        best = np.argmax(np.where(gated, log_lik, -np.inf), axis=1)
        W[np.flatnonzero(has), best[has]] = 1.0
    return W, (~has).astype(np.float64)
