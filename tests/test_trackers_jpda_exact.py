"""JPDA without enumeration (EHM) and from the k best events (Murty), against oracles written here:
brute-force enumeration of every assignment (small problems) and a dense dynamic programme over all
subsets of tracks (11 x 17 clusters), with per-track P_D and both P_G forms (thesis §4.4)."""

import itertools
import math
import statistics
import time

import numpy as np
import pytest

from roadtrack.trackers import AssociationParams, JPDAOverflowError, jpda
from roadtrack.trackers.association.ehm import net_marginals, plan
from roadtrack.trackers.association.jpda import clusters
from roadtrack.trackers.association.params import joint_event_terms
from roadtrack.trackers.gating import gate, mahalanobis2_and_log_gaussian

LAM = 0.05


def params(use_pg: bool, **kw) -> AssociationParams:
    return AssociationParams(pd=0.9, pg=0.99, clutter_density=LAM, use_pg=use_pg, **kw)


def event_factors(log_lik, p, pd):
    """(assigned (T, M), missed (T,)) linear factors of (4.19) from first principles: thesis form
    P_D N / lambda and 1 - P_D; P_D P_G form P_D P_G (N / P_G) / lambda and 1 - P_D P_G."""
    pde = pd * p.pg if p.use_pg else pd
    n = np.exp(log_lik) / (p.pg if p.use_pg else 1.0)
    return pde[:, None] * n / p.clutter_density, 1.0 - pde


def brute_force(log_lik, gated, p, pd):
    """Per cluster (a track without gated measurement: w0 = 1), every map of each measurement to {clutter,
    track 0..T-1}, kept if gated and one-to-one; a cluster without an event of positive weight is not updated."""
    T, M = log_lik.shape
    W, w0 = np.zeros((T, M)), np.ones(T)
    for ts, ms in clusters(gated):
        ix = np.ix_(ts, ms)
        W[ix], w0[ts] = brute_force_cluster(log_lik[ix], gated[ix], p, pd[ts])
    return W, w0


def brute_force_cluster(log_lik, gated, p, pd):
    T, M = log_lik.shape
    assigned, missed = event_factors(log_lik, p, pd)
    W, w0, c = np.zeros((T, M)), np.zeros(T), 0.0
    for src in itertools.product(range(-1, T), repeat=M):
        used = [t for t in src if t >= 0]
        if len(used) != len(set(used)) or any(t >= 0 and not gated[t, j] for j, t in enumerate(src)):
            continue
        w = math.prod(assigned[t, j] for j, t in enumerate(src) if t >= 0)
        w *= math.prod(missed[t] for t in range(T) if t not in used)
        c += w
        for j, t in enumerate(src):
            if t >= 0:
                W[t, j] += w
        for t in range(T):
            if t not in used:
                w0[t] += w
    if c == 0.0:  # no event of positive probability: no update
        return np.zeros((T, M)), np.ones(T)
    return W / c, w0 / c


def subset_dp(log_lik, gated, p, pd):
    """Exact marginals by a forward-backward programme over measurements whose state is the set of tracks
    already used (all 2^T subsets, dense, log space): an exact method independent of the EHM net."""
    T, M = log_lik.shape
    assigned, missed = event_factors(log_lik, p, pd)
    with np.errstate(divide="ignore"):
        la, lb = np.log(np.where(gated, assigned, 0.0)), np.log(missed)
    S = np.arange(1 << T)
    has = [(S >> t) & 1 == 1 for t in range(T)]
    f = [np.where(S == 0, 0.0, -np.inf)]
    for j in range(M):
        new = f[-1].copy()  # z_j is clutter
        for t in np.flatnonzero(gated[:, j]):  # z_j is track t's: from the subsets without t
            new[has[t]] = np.logaddexp(new[has[t]], f[-1][S[has[t]] ^ (1 << t)] + la[t, j])
        f.append(new)
    g = [None] * (M + 1)
    g[M] = sum(np.where(has[t], 0.0, lb[t]) for t in range(T))  # tracks never used are missed
    for j in range(M - 1, -1, -1):
        new = g[j + 1].copy()
        for t in np.flatnonzero(gated[:, j]):
            free = ~has[t]
            new[free] = np.logaddexp(new[free], g[j + 1][S[free] | (1 << t)] + la[t, j])
        g[j] = new
    log_c = np.logaddexp.reduce(f[M] + g[M])
    W = np.zeros((T, M))
    for j in range(M):
        for t in np.flatnonzero(gated[:, j]):
            free = ~has[t]
            W[t, j] = np.exp(np.logaddexp.reduce(f[j][free] + la[t, j] + g[j + 1][S[free] | (1 << t)]) - log_c)
    w0 = np.array([np.exp(np.logaddexp.reduce((f[M] + g[M])[~has[t]]) - log_c) for t in range(T)])
    return W, w0


def random_problem(rng, T, M):
    log_lik = rng.uniform(-6.0, 2.0, size=(T, M))
    gated = rng.random((T, M)) < rng.uniform(0.2, 0.9)
    pd = rng.choice([0.0, 0.5, 0.9, 0.99, 1.0], size=T)
    return log_lik, gated, pd


def highway_cluster(seed, T=11, n_clutter=6, sigma=1.2, alpha=16.0):
    """T cars on 3 lanes 3.5 m apart, 3 m apart along the road (staggered), position std sigma [m], one
    detection each plus n_clutter points within 3 m (per axis) of random cars; drawn until the gates make one
    cluster of T x (T + n_clutter) (about 2 tracks per measurement)."""
    rng = np.random.default_rng(seed)
    while True:
        z_hat = np.c_[np.arange(T) * 3.0 + rng.normal(0.0, 0.5, T), (np.arange(T) % 3) * 3.5]
        S = np.array([np.diag(rng.uniform(0.8, 1.2, 2)) * sigma**2 for _ in range(T)])
        clutter = z_hat[rng.integers(0, T, n_clutter)] + rng.uniform(-3.0, 3.0, (n_clutter, 2))
        Z = np.r_[z_hat + rng.normal(0.0, sigma, (T, 2)), clutter]
        d2, log_lik = mahalanobis2_and_log_gaussian(Z[None] - z_hat[:, None], S)
        gated = gate(d2, alpha)
        found = clusters(gated)
        if len(found) == 1 and found[0][0].size == T and found[0][1].size == len(Z):
            return log_lik, gated


def cluster_marginals(log_lik, gated, p, pd, backend):
    """EHM on one cluster through net_marginals with a forced backend (rows = measurements)."""
    a, b = joint_event_terms(log_lik, p, pd)
    res = net_marginals(a.T, gated.T, np.zeros(gated.shape[1]), b, 1 << 22, backend)
    return (np.zeros(gated.shape), np.ones(len(gated))) if res is None else (res[0].T, res[2])


@pytest.mark.parametrize("use_pg", [False, True])
def test_ehm_equals_enumeration_and_brute_force_on_random_problems(use_pg):
    p = params(use_pg)
    rng = np.random.default_rng(21)
    for _ in range(150):
        log_lik, gated, pd = random_problem(rng, rng.integers(1, 5), rng.integers(0, 6))
        ref = brute_force(log_lik, gated, p, pd)
        for method in ("ehm", "enumerate"):
            W, w0 = jpda(log_lik, gated, p, pd, method=method)
            np.testing.assert_allclose(W, ref[0], rtol=0, atol=1e-12)
            np.testing.assert_allclose(w0, ref[1], rtol=0, atol=1e-12)


@pytest.mark.parametrize("backend", ["python", "numpy"])
def test_both_ehm_evaluations_equal_enumeration_with_tracks_or_measurements_as_rows(backend):
    rng = np.random.default_rng(22)
    for i in range(120):
        p = params(bool(i % 2))
        T, M = rng.integers(2, 7), rng.integers(1, 8)
        log_lik, gated, pd = random_problem(rng, T, M)
        gated[:, 0] = True  # one cluster: every track gates z_0
        keep = gated.any(axis=0)
        a, b = joint_event_terms(log_lik[:, keep], p, pd)
        g = gated[:, keep]
        rows_meas = net_marginals(a.T, g.T, np.zeros(len(a.T)), b, 1 << 22, backend)
        rows_track = net_marginals(a, g, b, np.zeros(len(a.T)), 1 << 22, backend)
        W, w0 = jpda(log_lik, gated, p, pd, method="enumerate")
        if rows_meas is None:
            assert rows_track is None and np.all(w0 == 1.0)
            continue
        np.testing.assert_allclose(rows_meas[0].T, W[:, keep], rtol=0, atol=1e-12)
        np.testing.assert_allclose(rows_meas[2], w0, rtol=0, atol=1e-12)
        np.testing.assert_allclose(rows_track[0], W[:, keep], rtol=0, atol=1e-12)
        np.testing.assert_allclose(rows_track[1], w0, rtol=0, atol=1e-12)


@pytest.mark.parametrize("use_pg", [False, True])
def test_ehm_equals_subset_programme_on_11_by_17_clusters(use_pg):
    """Realistic highway clusters (frontier 2-4 tracks) and a dense random one (11 x 17, half the pairs
    gated), per-track P_D: both EHM evaluations against the dense subset programme to 1e-12."""
    p = params(use_pg)
    rng = np.random.default_rng(23)
    problems = [highway_cluster(seed) for seed in (0, 1)]
    dense = rng.random((11, 17)) < 0.5
    dense[:, 0] = True
    problems.append((rng.uniform(-6.0, 2.0, (11, 17)), dense))
    for log_lik, gated in problems:
        pd = rng.uniform(0.5, 1.0, 11)
        W_ref, w0_ref = subset_dp(log_lik, gated, p, pd)
        for backend in ("python", "numpy"):
            W, w0 = cluster_marginals(log_lik, gated, p, pd, backend)
            np.testing.assert_allclose(W, W_ref, rtol=0, atol=1e-12)
            np.testing.assert_allclose(w0, w0_ref, rtol=0, atol=1e-12)
        W, w0 = jpda(log_lik, gated, p, pd)
        np.testing.assert_allclose(W, W_ref, rtol=0, atol=1e-12)
        np.testing.assert_allclose(w0, w0_ref, rtol=0, atol=1e-12)


def test_highway_cluster_is_a_narrow_net_and_fast():
    """The 11 x 17 highway cluster: frontier of at most 4 tracks; the median of 20 jpda calls under 25 ms
    (the target is 5 ms on an idle machine: 1 ms measured; the bound leaves room for a loaded one)."""
    log_lik, gated = highway_cluster(0)
    _, width, _, _ = plan(gated.T)
    assert width <= 4
    p = params(False)
    times = []
    for _ in range(20):
        t0 = time.perf_counter()
        jpda(log_lik, gated, p)
        times.append(time.perf_counter() - t0)
    assert statistics.median(times) < 0.025


@pytest.mark.parametrize("use_pg", [False, True])
def test_k_best_is_exact_once_k_covers_every_event(use_pg):
    p = params(use_pg)
    rng = np.random.default_rng(24)
    for _ in range(60):
        log_lik, gated, pd = random_problem(rng, rng.integers(1, 5), rng.integers(0, 6))
        W, w0 = jpda(log_lik, gated, p, pd, method="k_best", k=10_000)
        W_ref, w0_ref = brute_force(log_lik, gated, p, pd)
        np.testing.assert_allclose(W, W_ref, rtol=0, atol=1e-12)
        np.testing.assert_allclose(w0, w0_ref, rtol=0, atol=1e-12)


def kbest_problem(rng, T, n_clutter=3, pd=0.9, lam=0.05, alpha=16.0):
    """The k_best error problem set of trackers/association/kbest.py: T tracks uniform in a 10 m square,
    S = I, one detection per track (N(0, I) about it) and n_clutter uniform points in the square."""
    z_hat = rng.uniform(0.0, 10.0, (T, 2))
    Z = np.r_[z_hat + rng.normal(size=(T, 2)), rng.uniform(0.0, 10.0, (n_clutter, 2))]
    d2, log_lik = mahalanobis2_and_log_gaussian(Z[None] - z_hat[:, None], np.repeat(np.eye(2)[None], T, axis=0))
    return log_lik, gate(d2, alpha), AssociationParams(pd=pd, pg=1.0 - math.exp(-alpha / 2), clutter_density=lam)


def kbest_errors(T, ks, n_problems, seed=2024):
    """Max abs marginal error of k_best against EHM over the first n_problems of the set, for each k."""
    rng = np.random.default_rng(seed)
    err = dict.fromkeys(ks, 0.0)
    for _ in range(n_problems):
        log_lik, gated, p = kbest_problem(rng, T)
        W, w0 = jpda(log_lik, gated, p)
        for k in ks:
            Wk, w0k = jpda(log_lik, gated, p, method="k_best", k=k)
            err[k] = max(err[k], np.abs(Wk - W).max(initial=0.0), np.abs(w0k - w0).max(initial=0.0))
    return err


def test_k_best_errors_stay_within_the_documented_table():
    """The first 40 problems of the documented 3 x 6 and 5 x 8 sets: errors at most the table's maxima
    over 200 (trackers/association/kbest.py), and smaller for larger k."""
    e3 = kbest_errors(3, (10, 100), 40)
    e5 = kbest_errors(5, (10, 100), 40)
    assert e3[10] <= 0.23 and e3[100] <= 1.5e-3 and e3[100] < e3[10]
    assert e5[10] <= 0.42 and e5[100] <= 0.099 and e5[100] < e5[10]


def test_clusters_without_a_positive_event_are_not_updated_by_any_method():
    """P_D = 1 for two tracks that gate only one shared measurement: every event has probability 0."""
    log_lik = np.array([[-1.0, 0.0], [-2.0, 0.0]])
    gated = np.array([[True, False], [True, False]])
    for method in ("ehm", "enumerate", "k_best"):
        W, w0 = jpda(log_lik, gated, params(False), np.array([1.0, 1.0]), method=method)
        np.testing.assert_array_equal(W, 0.0)
        np.testing.assert_array_equal(w0, 1.0)


def test_ehm_guard_is_a_one_line_error_and_enumerate_caps_do_not_apply():
    rng = np.random.default_rng(25)
    log_lik, gated = rng.uniform(-3, 1, (6, 8)), np.ones((6, 8), dtype=bool)
    p = params(False, max_events=1, on_overflow="raise")  # enumerate's cap: ignored by ehm
    W, w0 = jpda(log_lik, gated, p)
    np.testing.assert_allclose(W.sum(axis=1) + w0, 1.0, rtol=0, atol=1e-12)
    with pytest.raises(JPDAOverflowError, match=r"^JPDA \(ehm\) cluster of 8x6 .* max_nodes=100 [^\n]*$"):
        jpda(log_lik, gated, p, max_nodes=100)
    with pytest.raises(ValueError, match="method"):
        jpda(log_lik, gated, p, method="murty")


def test_ehm_is_exact_over_extreme_likelihood_ranges():
    """log-likelihoods spread over +-300 (event weights spanning e^1000): the linear-space evaluation is not
    chosen, and the log-space one still equals enumeration to 1e-12."""
    rng = np.random.default_rng(26)
    p = params(False)
    for _ in range(40):
        T, M = rng.integers(2, 5), rng.integers(2, 7)
        log_lik, gated, pd = random_problem(rng, T, M)
        log_lik = rng.uniform(-300.0, 300.0, (T, M))
        W, w0 = jpda(log_lik, gated, p, pd)
        W_ref, w0_ref = jpda(log_lik, gated, p, pd, method="enumerate")
        np.testing.assert_allclose(W, W_ref, rtol=0, atol=1e-12)
        np.testing.assert_allclose(w0, w0_ref, rtol=0, atol=1e-12)
