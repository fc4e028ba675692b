"""Exact JPDA marginals without enumerating joint events: efficient hypothesis management (EHM).

Maskell, Briers & Wright (2004), "Fast mutual exclusion", Proc. SPIE 5428; Horridge & Maskell (2006),
"Real-time tracking of hundreds of targets with efficient exact JPDAF implementation", FUSION. The JPDA
joint events of one cluster (thesis §4.4, (4.19)) are the partial matchings of its bipartite gate
graph: each measurement goes to one gated track or to clutter, each track takes at most one
measurement. Their weight factorises over the matching:

    P(Theta) prop. to  prod_{(t, j) in Theta} exp(a[t, j])  prod_{t unmatched} exp(b[t])        (4.19)

(a, b from `joint_event_terms`; an unmatched measurement, i.e. clutter, has factor 1). So a partial
event that has decided the first i "rows" (measurements, or tracks) influences the rest only through
which of the still-relevant "columns" it has used. The net:

* rows are processed in a greedy order that keeps the frontier small; the frontier after row i is the
  set of columns gated by some processed and by some unprocessed row;
* a node of layer i is a subset of the frontier (the used frontier columns, an int bitmask over slots
  that a column holds from its first to its last gated row); partial events with the same node are
  merged (weights summed), which is what makes the net polynomial where the event tree is exponential;
* row i's choices from node K: unmatched (weight r0[i]) or a gated column c not in K (weight A[i, c]);
  a column leaves the frontier after its last gated row, with factor c0[c] if it was never used;
* forward sums alpha(node), backward sums beta(node) (sum over completions); the marginal of an edge
  is alpha(parent) w(edge) beta(child) / c, with c the (4.19) normaliser. Every event crosses each layer
  by exactly one edge, so a layer's edge marginals sum to 1: summing them by choice gives beta_jt (4.21),
  and the column-closing edges give the unmatched (missed track) marginals beta_0t.

Two evaluations of the same net, both exact to rounding (tests: 1e-12 against enumeration):
* small nets (road traffic: chains of overlapping gates, frontier of 2-4 tracks): plain Python dicts
  in linear space, the weights first scaled so that every row's and column's best option is 1; used
  when the edge bound below is at most 1000 (where numpy's per-call overhead dominates) and the event
  weights then span less than e^-500, so that no partial sum can underflow [D];
* otherwise numpy arrays in log space (group log-sum-exp over sorted node keys), keys int64 bitmasks:
  a cluster keeping more than 62 columns open at once is refused (JPDAOverflowError).

Cost. Let w be the largest frontier of the order and k_i the number of gated columns of row i. Layer i
has at most min(2^w, partial events) nodes and (1 + k_i) times as many edges: O(sum_i 2^w (1 + k_i))
in the worst case (every track gating every measurement: w = min(T, M), as rows are the larger side),
O(R) layers of a few nodes for chain-like clusters. `max_nodes` bounds the edges of one layer (memory
guard): above it JPDAOverflowError, raised before the layer is allocated. Measured on a 2-core machine:
11 x 17 highway clusters (tests/test_trackers_jpda_exact.highway_cluster, w = 2-4, 321 122 joint events
in the benchmark's one) 0.8-1.8 ms; the same with position std 3 m (w = 8, 6 tracks per measurement)
2-3 ms; an 11 x 17 cluster with every pair gated (w = 11) 25-33 ms; 15 x 20 with half the pairs gated
about 0.2 s.
"""

from __future__ import annotations

import numpy as np

from roadtrack.trackers.errors import JPDAOverflowError

_MAX_BITS = 62  # numpy node keys are int64 bitmasks over frontier slots
_SMALL_EDGES = 1000  # nets with at most this many edges (upper bound) are evaluated in plain Python [D]
_SPAN = 500.0  # linear space only if event log-weights span less than this [D]


def plan(G: np.ndarray) -> tuple[list[tuple[int, list[int], list[int], list[int], list[int]]], int, int, int]:
    """Processing order of the rows of G (R, C) bool, greedy on the frontier size, and per layer
    (row, gated columns, their slot bits, closing columns, their bits); also the largest frontier width,
    the bound sum_i 2^open_i (1 + k_i) on the number of edges and the number of key bits used.

    The next row is the one leaving the fewest open columns (gated by a processed and an unprocessed
    row), ties broken by fewer newly opened columns, then by the smaller index."""
    R, C = G.shape
    rows, cols = np.nonzero(G)
    adj: list[list[int]] = [[] for _ in range(R)]
    cadj: list[list[int]] = [[] for _ in range(C)]
    for r, c in zip(rows.tolist(), cols.tolist()):
        adj[r].append(c)
        cadj[c].append(r)
    remaining = [len(x) for x in cadj]  # unprocessed rows gating each column
    opened = [len(x) for x in adj]  # per row: its columns not yet touched
    closed = [sum(1 for c in x if remaining[c] == 1) for x in adj]  # per row: its columns it would close
    todo = set(range(R))
    n_open, width, bound, bits_used = 0, 0, 0, 0
    slot = [-1] * C
    free: list[int] = list(range(C))[::-1]  # smallest free slot first
    layers = []
    for _ in range(R):
        r = min(todo, key=lambda q: (opened[q] - closed[q], opened[q], q))
        todo.discard(r)
        bound += (1 << n_open) * (1 + len(adj[r]))
        n_open += opened[r] - closed[r]
        width = max(width, n_open)
        cand = adj[r]
        closing = []
        for c in cand:
            if slot[c] < 0:  # first gated row of c: it takes a slot
                slot[c] = free.pop()
                for q in cadj[c]:
                    opened[q] -= 1
            remaining[c] -= 1
            if remaining[c] == 0:
                closing.append(c)
            elif remaining[c] == 1:
                for q in cadj[c]:
                    if q in todo:
                        closed[q] += 1
        bits_used = max(bits_used, C - len(free))
        layers.append((r, cand, [1 << slot[c] for c in cand], closing, [1 << slot[c] for c in closing]))
        free.extend(slot[c] for c in closing)
    return layers, width, bound, bits_used


def _overflow(what: str, max_nodes: int) -> JPDAOverflowError:
    return JPDAOverflowError(f"JPDA (ehm) cluster of {what} needs more than max_nodes={max_nodes} edges in one "
                             f"layer; use method 'k_best' or a smaller gate")


def _net_python(A: np.ndarray, r0: np.ndarray, c0: np.ndarray, layers: list, max_nodes: int,
                what: str) -> tuple | None:
    """The net in linear space with Python dicts (A, r0, c0 linear weights, each <= 1)."""
    R, C = A.shape
    # per layer: choices (index, bit, weight) with weight > 0 (index 0: row unmatched), closing (bit, c0)
    plans = [([(i, b, w) for i, (b, w) in enumerate(zip([0, *bits], [r0[r], *A[r, cand]])) if w > 0.0],
              list(zip(cbits, c0[closing])), sum(cbits)) for r, cand, bits, closing, cbits in layers]
    alphas, nodes = [], {0: 1.0}
    for (choices, close, mask), (r, cand, *_) in zip(plans, layers):
        if len(nodes) * (1 + len(cand)) > max_nodes:
            raise _overflow(what, max_nodes)
        new: dict[int, float] = {}
        for key, val in nodes.items():
            for _, bit, w in choices:
                if not key & bit:
                    f = w
                    for cb, miss in close:  # a column seen for the last time: c0 if never used
                        if not (key | bit) & cb:
                            f *= miss
                    if f:
                        child = (key | bit) & ~mask  # ... then forgotten
                        new[child] = new.get(child, 0.0) + val * f
        top = max(new.values(), default=0.0)
        if top == 0.0:
            return None
        alphas.append(nodes)
        nodes = {key: val / top for key, val in new.items()}  # rescaled per layer; marginals are ratios
    P, p_r, p_c = np.zeros((R, C)), np.zeros(R), np.zeros(C)
    beta = {0: 1.0}
    for (choices, close, mask), (r, cand, _, closing, _), alpha in zip(reversed(plans), reversed(layers),
                                                                        reversed(alphas)):
        m = [0.0] * (len(cand) + 1)
        mc = [0.0] * len(closing)
        prev: dict[int, float] = {}
        for key, val in alpha.items():
            back = 0.0
            for i, bit, w in choices:
                if key & bit:
                    continue
                f = w
                for cb, miss in close:
                    if not (key | bit) & cb:
                        f *= miss
                t = f * beta.get((key | bit) & ~mask, 0.0)
                if t:
                    back += t
                    m[i] += val * t  # (4.21) alpha(parent) w(edge) beta(child)
                    for j, (cb, _) in enumerate(close):
                        if not (key | bit) & cb:
                            mc[j] += val * t  # column closed unused: the track was missed (4.21) beta_0t
            prev[key] = back
        z = sum(m)  # every event crosses this layer once: its edge marginals sum to c
        p_r[r] = m[0] / z
        P[r, cand] = np.array(m[1:]) / z
        p_c[closing] = np.array(mc) / z
        top = max(prev.values())
        beta = {key: val / top for key, val in prev.items()}
    return P, p_r, p_c


def _group_lse(v: np.ndarray, starts: np.ndarray, gid: np.ndarray) -> np.ndarray:
    """log-sum-exp of v (finite or -inf) over consecutive groups beginning at `starts` (gid: group of v)."""
    mx = np.maximum.reduceat(v, starts)
    mx[~np.isfinite(mx)] = 0.0  # a group of -inf only: exp gives 0 and the result -inf
    with np.errstate(divide="ignore"):
        return mx + np.log(np.add.reduceat(np.exp(v - mx[gid]), starts))


def _groups(keys_sorted: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(starts, gid) of the runs of equal values in a sorted array."""
    head = np.empty(keys_sorted.size, dtype=bool)
    head[:1] = True
    np.not_equal(keys_sorted[1:], keys_sorted[:-1], out=head[1:])
    return np.flatnonzero(head), np.cumsum(head) - 1


def _net_numpy(A: np.ndarray, r0: np.ndarray, c0: np.ndarray, layers: list, max_nodes: int,
               what: str) -> tuple | None:
    """The net in log space with numpy arrays (A, r0, c0 log weights)."""
    R, C = A.shape
    keys, la = np.zeros(1, dtype=np.int64), np.zeros(1)
    saved = []
    for r, cand, bits, closing, cbits in layers:
        bits = np.array([0, *bits], dtype=np.int64)  # choice 0: row unmatched (clutter, or track missed)
        w = np.concatenate([[r0[r]], A[r, cand]])
        if keys.size * bits.size > max_nodes:
            raise _overflow(what, max_nodes)
        ok = ((keys[:, None] & bits[None, :]) == 0) & np.isfinite(w)[None, :]  # column still free in this node
        par, ch = np.nonzero(ok)  # row-major: parents nondecreasing
        ck = keys[par] | bits[ch]
        ew = w[ch]
        miss = None
        if closing:  # columns seen for the last time: factor c0 if never used, then forgotten
            cb = np.array(cbits, dtype=np.int64)
            miss = (ck[:, None] & cb[None, :]) == 0
            ew = ew + np.where(miss, c0[closing][None, :], 0.0).sum(axis=1)
            ck &= ~np.bitwise_or.reduce(cb)
            fin = np.isfinite(ew)
            if not fin.all():
                par, ch, ck, ew, miss = par[fin], ch[fin], ck[fin], ew[fin], miss[fin]
        if ck.size == 0:
            return None
        ev = la[par] + ew  # (4.19) partial-event log weights, summed per child node below
        srt = np.argsort(ck, kind="stable")
        starts, gid = _groups(ck[srt])
        child = np.empty_like(gid)
        child[srt] = gid
        saved.append((r, cand, closing, par, ch, ew, child, miss, la))
        keys, la = ck[srt][starts], _group_lse(ev[srt], starts, gid)
    P, p_r, p_c = np.zeros((R, C)), np.zeros(R), np.zeros(C)
    lb = np.zeros(1)  # backward sum of the final node (every column closed: key 0)
    for r, cand, closing, par, ch, ew, child, miss, la_prev in reversed(saved):
        t = ew + lb[child]
        lm = la_prev[par] + t  # log alpha(parent) w(edge) beta(child)
        pe = np.exp(lm - lm.max())
        pe /= pe.sum()  # every event crosses each layer once: edge marginals of a layer sum to 1 (4.21)
        m = np.bincount(ch, weights=pe, minlength=len(cand) + 1)
        p_r[r], P[r, cand] = m[0], m[1:]
        if miss is not None:
            p_c[closing] = pe @ miss
        starts, gid = _groups(par)
        lb = np.full(la_prev.size, -np.inf)
        lb[par[starts]] = _group_lse(t, starts, gid)
    return P, p_r, p_c


def net_marginals(A: np.ndarray, G: np.ndarray, r0: np.ndarray, c0: np.ndarray, max_nodes: int,
                  backend: str | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """Marginals of the weighted partial matchings of a connected bipartite graph, by the EHM net.

    A (R, C) log edge weights (read where G); G (R, C) bool, every row and column with an edge;
    r0 (R,), c0 (C,) log weights of an unmatched row / column (may be -inf). Returns
    (P (R, C) edge marginals, p_r (R,) row-unmatched, p_c (C,) column-unmatched marginals), or None when
    no matching has positive weight. Raises JPDAOverflowError if one layer would exceed max_nodes edges.
    backend: "python" or "numpy" to force one evaluation (tests), None to choose (module docstring)."""
    R, C = G.shape
    layers, width, bound, bits_used = plan(G)
    what = f"{R}x{C} (frontier width {width})"
    A = np.where(G, A, -np.inf)
    # scale every row's and then every column's options so that the best is 1 (log 0): invariant, as each
    # event takes exactly one option per row and per column
    u = np.maximum(r0, A.max(axis=1))
    u = np.where(np.isfinite(u), u, 0.0)
    As, r0s = A - u[:, None], r0 - u
    v = np.maximum(c0, As.max(axis=0))
    v = np.where(np.isfinite(v), v, 0.0)
    As, c0s = As - v[None, :], c0 - v
    with np.errstate(invalid="ignore"):  # every event weight is at least exp(-span) (or exactly 0)
        row_min = np.where(G & np.isfinite(As), As, np.inf).min(axis=1)
        span = -(np.minimum(np.where(np.isfinite(r0s), r0s, 0.0), row_min).sum()
                 + np.minimum(np.where(np.isfinite(c0s), c0s, 0.0), 0.0).sum())
    if backend == "python" or (backend is None and bound <= _SMALL_EDGES and span < _SPAN):
        return _net_python(np.exp(As), np.exp(r0s), np.exp(c0s), layers, max_nodes, what)
    if bits_used > _MAX_BITS:
        raise JPDAOverflowError(f"JPDA (ehm) cluster of {what} keeps more than {_MAX_BITS} columns open; "
                                f"use method 'k_best'")
    return _net_numpy(A, r0, c0, layers, max_nodes, what)
