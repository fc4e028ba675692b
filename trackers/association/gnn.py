"""Global nearest neighbour: the single most probable feasible joint event (scipy linear_sum_assignment)."""

from __future__ import annotations

import numpy as np
from scipy.optimize import linear_sum_assignment

from roadtrack.trackers.association.params import AssociationParams, check_inputs, joint_event_terms, track_pd

_FORBIDDEN_MISS = 1e12  # cost of a miss when P_D = 1: chosen only if no feasible assignment remains


def global_nearest_neighbour(log_lik: np.ndarray, gated: np.ndarray, p: AssociationParams,
                             pd: np.ndarray | float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Hard weights of argmax_Theta P(Theta) over feasible joint events (the JPDA events of (4.19), same
    P_D / P_G form as `jpda`): each measurement goes to at most one track, each track gets at most one
    gated measurement or is missed. Solved as an assignment on the (T, M + T) cost matrix
    [-a (inf where not gated) | diag(-b)], a and b from `joint_event_terms`. pd: per-track P_D or None."""
    log_lik, gated = check_inputs(log_lik, gated)
    T, M = log_lik.shape
    W = np.zeros((T, M))
    w0 = np.ones(T)
    rows = np.flatnonzero(gated.any(axis=1))
    cols = np.flatnonzero(gated.any(axis=0))
    if rows.size == 0:
        return W, w0
    a, b = joint_event_terms(log_lik[np.ix_(rows, cols)], p, track_pd(p, T, pd)[rows])
    g = gated[np.ix_(rows, cols)]
    n = rows.size
    cost = np.full((n, cols.size + n), np.inf)
    cost[:, :cols.size] = np.where(g, -a, np.inf)
    cost[np.arange(n), cols.size + np.arange(n)] = np.where(np.isfinite(b), -b, _FORBIDDEN_MISS)
    r, c = linear_sum_assignment(cost)
    hit = c < cols.size
    W[rows[r[hit]], cols[c[hit]]] = 1.0
    w0[rows[r[hit]]] = 0.0
    return W, w0
