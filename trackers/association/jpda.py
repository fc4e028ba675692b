"""Joint probabilistic data association, exact per cluster (thesis §4.4, (4.18)-(4.21)).

1. Validation matrix: measurement j may come from track t iff gated[t, j] (clutter always).
2. Clusters: connected components of the bipartite track-measurement gate graph [R] (Fortmann et al.).
   A track with no gated measurement has w0 = 1; one-track clusters are computed together in one batch
   (their events are 'all clutter' and 'z_j is the track's', so this is the same formula).
3. Event log-weight (4.19): sum of a[t, j] over assigned pairs + b[t] per undetected track (see
   `joint_event_terms`: thesis form or P_D P_G form, per-track P_D); normalised per cluster (the
   constant c); marginals beta_jt and beta_0t (4.21).

Methods for a cluster of two or more tracks (`method=`):
* "ehm" (default): exact marginals from the efficient-hypothesis-management net (`ehm.py`), without
  listing the joint events. Bounded by the net's frontier width w (<= min(T, M) of the cluster): at
  most 2^w nodes per layer. Budget: `max_nodes` edges in one layer (checked before the layer is
  allocated); max_events does not apply.
* "enumerate": every feasible joint event listed, measurement by measurement, with a 'used tracks'
  set per partial event (the depth-first tree of thesis §4.4 step 3, one vectorised level at a time).
  Exponential; kept as the test oracle. Budget: `p.max_events` feasible events of a cluster, checked
  before each level is allocated.
* "k_best": the k most probable events by Murty's ranked assignment (`kbest.py`), renormalised:
  approximate, exact when k >= the number of feasible events; measured errors in `kbest.py`. Its cost
  is bounded by k (no budget).

A cluster over its method's budget (a dense motorway: 33 tracks x 29 measurements, frontier 18) is a
fallback for that cluster only, by `p.on_overflow`: "k_best" (default) gives its k-best marginals,
"pda" per-track PDA weights (with a JPDAOverflowWarning), "raise" a JPDAOverflowError (one line, naming
the cluster size). Every other cluster stays exact. `jpda_fallbacks` also returns which tracks fell back
(the tracker reports them as the diagnostic FALLBACK_DIAGNOSTIC, and the testbed counts the clusters).
"""

from __future__ import annotations

import warnings

import numpy as np

from roadtrack.trackers.association.ehm import net_marginals
from roadtrack.trackers.association.kbest import k_best_marginals
from roadtrack.trackers.association.logsum import logsumexp
from roadtrack.trackers.association.params import AssociationParams, check_inputs, joint_event_terms, track_pd
from roadtrack.trackers.association.pda import pda
from roadtrack.trackers.errors import JPDAOverflowError, JPDAOverflowWarning

METHODS = ("ehm", "enumerate", "k_best")
FALLBACK_DIAGNOSTIC = "jpda_fallback"
"""Per-track diagnostic of the jpda associator: 1 where the track's cluster was over budget and fell back
(p.on_overflow), NaN where it was associated exactly (so the diagnostics table holds rows only for fallbacks)."""
DEFAULT_K = 100
DEFAULT_MAX_NODES = 1 << 20


def components(gated: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Connected components of the gate graph by label propagation: (track labels (T,), measurement labels
    (M,)); a label is the smallest track index of the component, T for a track or measurement without edges."""
    T, M = gated.shape
    lab = np.where(gated.any(axis=1), np.arange(T), T)
    while True:
        mlab = np.where(gated, lab[:, None], T).min(axis=0, initial=T)
        new = np.minimum(lab, np.where(gated, mlab[None, :], T).min(axis=1, initial=T))
        if np.array_equal(new, lab):
            return lab, mlab
        lab = new


def fallback_clusters(gated: np.ndarray, fell_back: np.ndarray) -> int:
    """Number of clusters associated by a fallback in one scan: the gate graph's components (gated (T, M) bool)
    holding a track flagged in fell_back (T,) (bool, or the FALLBACK_DIAGNOSTIC values: 1 or NaN)."""
    flag = np.asarray(fell_back)
    flag = flag == 1 if flag.dtype != np.bool_ else flag
    if flag.shape != (gated.shape[0],):
        raise ValueError(f"fallback_clusters needs one flag per track ({gated.shape[0]},), got {flag.shape}")
    if not flag.any():  # no fallback (every scan but a dense one's): no components to label
        return 0
    lab, _ = components(gated)
    return int(np.unique(lab[flag]).size)


def clusters(gated: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """Connected components of the gate graph: list of (track indices, measurement indices), each sorted.

    Only tracks with at least one gated measurement appear; clusters are ordered by their first track."""
    lab, mlab = components(gated)
    return [(np.flatnonzero(lab == c), np.flatnonzero(mlab == c)) for c in np.unique(lab[lab < len(lab)])]


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


def _cluster_marginals(a: np.ndarray, b: np.ndarray, assign: np.ndarray,
                       used: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    Tc, Mc = a.shape
    E = len(assign)
    log_w = np.zeros(E)
    for j in range(Mc):
        tj = assign[:, j]
        hit = tj >= 0
        log_w[hit] += a[tj[hit], j]  # (4.19) lambda^-1 N(z_j; z_hat_t, S_t) P_D per assigned pair
    log_w += np.where(used, 0.0, b[None, :]).sum(axis=1)  # (4.19) (1 - P_D^t) per missed track t
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


def _ehm(a: np.ndarray, b: np.ndarray, g: np.ndarray, max_nodes: int) -> tuple[np.ndarray, np.ndarray] | None:
    """Exact cluster marginals by the EHM net; rows are the larger side (keys over the smaller)."""
    Tc, Mc = g.shape
    if Mc >= Tc:  # rows = measurements (unmatched: clutter, factor 1), columns = tracks (unmatched: b)
        res = net_marginals(a.T, g.T, np.zeros(Mc), b, max_nodes)
        return None if res is None else (res[0].T, res[2])
    res = net_marginals(a, g, b, np.zeros(Mc), max_nodes)
    return None if res is None else (res[0], res[1])


def _cluster(ts, ms, log_lik, gated, p, pdt, method, k, max_nodes):
    """(W, w0) of cluster (tracks ts, measurements ms) or None (no event of positive probability), and whether
    it fell back (over its method's budget, p.on_overflow)."""
    g = gated[np.ix_(ts, ms)]
    a, b = joint_event_terms(log_lik[np.ix_(ts, ms)], p, pdt[ts])
    if method == "k_best":
        return k_best_marginals(a, b, g, k), False
    if method == "ehm":
        try:
            return _ehm(a, b, g, max_nodes), False
        except JPDAOverflowError:
            if p.on_overflow == "raise":
                raise
            why = f"max_nodes={max_nodes}"
    else:
        events = enumerate_events(g, p.max_events)
        if events is not None:
            return _cluster_marginals(a, b, *events), False
        if p.on_overflow == "raise":
            raise JPDAOverflowError(f"JPDA cluster of {ts.size} tracks and {ms.size} measurements has more than "
                                    f"max_events={p.max_events} feasible joint events")
        why = f"max_events={p.max_events}"
    if p.on_overflow == "k_best":
        return k_best_marginals(a, b, g, k), True
    warning = JPDAOverflowWarning(f"JPDA cluster of {ts.size} tracks and {ms.size} measurements exceeds "
                                  f"{why}; using per-track PDA for it")
    warning.tracks, warning.measurements = int(ts.size), int(ms.size)  # for a caller's once-per-run summary
    warnings.warn(warning, stacklevel=4)
    return pda(log_lik[np.ix_(ts, ms)], g, p, pdt[ts]), True


def jpda(log_lik: np.ndarray, gated: np.ndarray, p: AssociationParams, pd: np.ndarray | float | None = None, *,
         method: str = "ehm", k: int = DEFAULT_K,
         max_nodes: int = DEFAULT_MAX_NODES) -> tuple[np.ndarray, np.ndarray]:
    """JPDA marginal association probabilities (T, M) and miss probabilities (T,). pd: per-track P_D (T,) or
    None for p.pd; method: "ehm" | "enumerate" | "k_best"; k: events kept by "k_best" (and by the k_best
    fallback); max_nodes: budget of "ehm". See module docstring. A cluster in which no event has positive
    probability (only possible with P_D = 1) is left unassociated (w0 = 1)."""
    W, w0, _ = jpda_fallbacks(log_lik, gated, p, pd, method=method, k=k, max_nodes=max_nodes)
    return W, w0


def jpda_fallbacks(log_lik: np.ndarray, gated: np.ndarray, p: AssociationParams,
                   pd: np.ndarray | float | None = None, *, method: str = "ehm", k: int = DEFAULT_K,
                   max_nodes: int = DEFAULT_MAX_NODES) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`jpda`, also returning fell_back (T,) bool: the tracks whose cluster was over its method's budget and was
    associated by the p.on_overflow fallback instead (the fallback clusters are the gate graph's components,
    `components`, holding such tracks)."""
    if method not in METHODS:
        raise ValueError(f"jpda method must be one of {list(METHODS)}, got {method!r}")
    log_lik, gated = check_inputs(log_lik, gated)
    T, M = log_lik.shape
    pdt = track_pd(p, T, pd)
    W = np.zeros((T, M))
    w0 = np.ones(T)
    fell_back = np.zeros(T, dtype=bool)
    lab, _ = components(gated)
    size = np.bincount(lab, minlength=T + 1)[:T]
    single = np.flatnonzero((lab < T) & (size[np.minimum(lab, T - 1)] == 1))
    if single.size:  # one-track clusters in one batch: the events are 'all clutter' or 'z_j is the track's'
        a, b = joint_event_terms(log_lik[single], p, pdt[single])
        terms = np.concatenate([b[:, None], np.where(gated[single], a, -np.inf)], axis=1)
        log_c = logsumexp(terms, axis=1, keepdims=True)  # (4.19) normalising constant c per cluster
        prob = np.exp(terms - log_c)  # finite: every such track has a gated measurement
        w0[single] = prob[:, 0]  # (4.21) beta_0t
        W[single] = prob[:, 1:]  # (4.21) beta_jt
    for c in np.flatnonzero(size > 1):
        ts = np.flatnonzero(lab == c)
        ms = np.flatnonzero(gated[ts].any(axis=0))
        res, fell_back[ts] = _cluster(ts, ms, log_lik, gated, p, pdt, method, k, max_nodes)
        if res is None:  # no event has positive probability (only possible with P_D = 1): no update
            continue
        W[np.ix_(ts, ms)] = np.clip(res[0], 0.0, 1.0)  # sums of probabilities may exceed 1 by an ulp
        w0[ts] = np.clip(res[1], 0.0, 1.0)
    return W, w0, fell_back
