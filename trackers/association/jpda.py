"""Joint probabilistic data association with exact per-cluster enumeration (thesis §4.4, (4.18)-(4.21)).

1. Validation matrix: measurement j may come from track t iff gated[t, j] (clutter always).
2. Clusters: connected components of the bipartite track-measurement gate graph [R] (Fortmann et al.).
   A track with no gated measurement has w0 = 1; one-track clusters are computed together in one batch
   (their events are 'all clutter' and 'z_j is the track's', so this is the same formula).
3. Feasible joint events of a cluster: every measurement gets one source (clutter or a gated track),
   every track at most one measurement. They are enumerated exactly, measurement by measurement,
   with a 'used tracks' set per partial event. This is the depth-first tree of thesis §4.4 step 3
   expanded one level at a time, so that each level is one vectorised numpy operation.
4. Event log-weight (4.19): sum of a[t, j] over assigned pairs + b per undetected track (see
   `joint_event_terms`); normalised per cluster with logsumexp (the constant c); marginals (4.21).

Combinatorial guard: if a cluster would have more than `p.max_events` feasible events, then with
`p.on_overflow == "raise"` a JPDAOverflowError is raised, and with "pda" (default) that cluster's
tracks get per-track PDA weights (`pda`) and a JPDAOverflowWarning is issued. The check is made
before each level is allocated, so an oversized cluster costs at most about `max_events` rows.
"""

from __future__ import annotations

import warnings

import numpy as np
from scipy.special import logsumexp

from trackers.association.params import AssociationParams, check_inputs, joint_event_terms
from trackers.association.pda import pda
from trackers.errors import JPDAOverflowError, JPDAOverflowWarning


def clusters(gated: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """Connected components of the gate graph: list of (track indices, measurement indices), each sorted.

    Only tracks with at least one gated measurement appear; clusters are ordered by their first track."""
    todo = gated.any(axis=1)
    out = []
    while todo.any():
        t_in = np.zeros(len(gated), dtype=bool)
        t_in[np.argmax(todo)] = True
        m_in = gated[t_in].any(axis=0)
        while True:  # grow: tracks gating any member measurement, measurements gated by any member track
            t_new = gated[:, m_in].any(axis=1)
            m_new = gated[t_new].any(axis=0)
            if (t_new == t_in).all() and (m_new == m_in).all():
                break
            t_in, m_in = t_new, m_new
        todo &= ~t_in
        out.append((np.flatnonzero(t_in), np.flatnonzero(m_in)))
    return out


def enumerate_events(gated: np.ndarray, max_events: int) -> tuple[np.ndarray, np.ndarray] | None:
    """All feasible joint events of one cluster: gated (Tc, Mc) ->
    (assign (E, Mc) int, -1 = clutter, else track index; used (E, Tc) bool), or None if E > max_events."""
    Tc, Mc = gated.shape
    assign = np.zeros((1, 0), dtype=np.int64)
    used = np.zeros((1, Tc), dtype=bool)
    for j in range(Mc):
        cands = np.flatnonzero(gated[:, j])
        free = [~used[:, t] for t in cands]
        if len(assign) + sum(int(f.sum()) for f in free) > max_events:
            return None
        new_assign = [np.concatenate([assign, np.full((len(assign), 1), -1)], axis=1)]  # z_j is clutter
        new_used = [used]
        for t, f in zip(cands, free):  # z_j is track t's, if t is still free in that partial event
            a_t = np.concatenate([assign[f], np.full((int(f.sum()), 1), t)], axis=1)
            u_t = used[f].copy()
            u_t[:, t] = True
            new_assign.append(a_t)
            new_used.append(u_t)
        assign = np.concatenate(new_assign, axis=0)
        used = np.concatenate(new_used, axis=0)
    return assign, used


def _cluster_marginals(a: np.ndarray, b: float, assign: np.ndarray,
                       used: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    Tc, Mc = a.shape
    E = len(assign)
    log_w = np.zeros(E)
    for j in range(Mc):
        tj = assign[:, j]
        hit = tj >= 0
        log_w[hit] += a[tj[hit], j]  # (4.19) lambda^-1 N(z_j; z_hat_t, S_t) P_D per assigned pair
    n_miss = Tc - used.sum(axis=1)
    log_w += np.where(n_miss > 0, n_miss * b if np.isfinite(b) else -np.inf, 0.0)  # (4.19) (1 - P_D) per missed track
    with np.errstate(divide="ignore", invalid="ignore"):
        log_c = logsumexp(log_w)  # (4.19) normalising constant c
    if not np.isfinite(log_c):
        return None
    prob = np.exp(log_w - log_c)
    W = np.empty((Tc, Mc))
    for j in range(Mc):
        W[:, j] = np.bincount(assign[:, j] + 1, weights=prob, minlength=Tc + 1)[1:]  # (4.21) beta_jt
    w0 = prob @ (~used)  # (4.21) beta_0t: events in which track t is undetected
    return np.minimum(W, 1.0), np.minimum(w0, 1.0)  # sums of normalised probabilities may exceed 1 by an ulp


def jpda(log_lik: np.ndarray, gated: np.ndarray, p: AssociationParams) -> tuple[np.ndarray, np.ndarray]:
    """JPDA marginal association probabilities (T, M) and miss probabilities (T,). See module docstring."""
    log_lik, gated = check_inputs(log_lik, gated)
    T, M = log_lik.shape
    W = np.zeros((T, M))
    w0 = np.ones(T)
    found = clusters(gated)
    single = np.array([ts[0] for ts, _ in found if ts.size == 1], dtype=np.int64)
    multi = [(ts, ms) for ts, ms in found if ts.size > 1]
    if single.size:  # one-track clusters in one batch: the events are 'all clutter' or 'z_j is the track's'
        a, b = joint_event_terms(log_lik[single], p)
        terms = np.concatenate([np.full((single.size, 1), b), np.where(gated[single], a, -np.inf)], axis=1)
        log_c = logsumexp(terms, axis=1, keepdims=True)  # (4.19) normalising constant c per cluster
        prob = np.exp(terms - log_c)  # finite: every such track has a gated measurement
        w0[single] = prob[:, 0]  # (4.21) beta_0t
        W[single] = prob[:, 1:]  # (4.21) beta_jt
    for ts, ms in multi:
        g = gated[np.ix_(ts, ms)]
        events = enumerate_events(g, p.max_events)
        if events is None:
            if p.on_overflow == "raise":
                raise JPDAOverflowError(f"JPDA cluster of {ts.size} tracks and {ms.size} measurements has more than "
                                        f"max_events={p.max_events} feasible joint events")
            warnings.warn(f"JPDA cluster of {ts.size} tracks and {ms.size} measurements exceeds max_events="
                          f"{p.max_events}; using per-track PDA for it", JPDAOverflowWarning, stacklevel=2)
            Wc, w0c = pda(log_lik[np.ix_(ts, ms)], g, p)
        else:
            a, b = joint_event_terms(log_lik[np.ix_(ts, ms)], p)
            res = _cluster_marginals(a, b, *events)
            if res is None:  # no event has positive probability (only possible with P_D = 1): no update
                continue
            Wc, w0c = res
        W[np.ix_(ts, ms)] = Wc
        w0[ts] = w0c
    return W, w0
