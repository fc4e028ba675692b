"""Associators against independent brute force, PDA closed form, and hypothesis properties."""

import itertools
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from trackers import ASSOCIATORS, AssociationParams, JPDAOverflowError, JPDAOverflowWarning, jpda, pda
from trackers.association.jpda import clusters

P = AssociationParams(pd=0.9, pg=0.99966, clutter_density=1e-2)


def random_case(rng, T, M, density=0.6):
    log_lik = rng.uniform(-6.0, 2.0, size=(T, M))
    gated = rng.random((T, M)) < density
    return log_lik, gated


def brute_force_events(log_lik, gated, p):
    """Every assignment of each measurement to {clutter, track 1..T}, kept if gated and one-to-one, with the
    thesis (4.19) weight prod_j [N/lambda]^tau_j prod_t P_D^delta_t (1 - P_D)^(1 - delta_t) (P_D P_G form:
    P_D -> P_D P_G, N -> N / P_G). Returns list of (sources, weight); source -1 = clutter."""
    T, M = log_lik.shape
    pd = p.pd * p.pg if p.use_pg else p.pd
    events = []
    for src in itertools.product(range(-1, T), repeat=M):
        assigned = [t for t in src if t >= 0]
        if len(assigned) != len(set(assigned)) or any(t >= 0 and not gated[t, j] for j, t in enumerate(src)):
            continue
        w = 1.0
        for j, t in enumerate(src):
            if t >= 0:
                n = math.exp(log_lik[t, j]) / (p.pg if p.use_pg else 1.0)
                w *= n / p.clutter_density
        for t in range(T):
            w *= pd if t in assigned else (1.0 - pd)
        events.append((src, w))
    return events


def brute_force_jpda(log_lik, gated, p):
    T, M = log_lik.shape
    events = brute_force_events(log_lik, gated, p)
    c = sum(w for _, w in events)
    W = np.zeros((T, M))
    w0 = np.zeros(T)
    for src, w in events:
        for j, t in enumerate(src):
            if t >= 0:
                W[t, j] += w / c
        for t in range(T):
            if t not in src:
                w0[t] += w / c
    return W, w0


@pytest.mark.parametrize("use_pg", [False, True])
def test_jpda_equals_brute_force_enumeration(use_pg):
    p = AssociationParams(pd=0.85, pg=0.99, clutter_density=0.05, use_pg=use_pg)
    rng = np.random.default_rng(11)
    for _ in range(60):
        T, M = rng.integers(1, 5), rng.integers(0, 6)
        log_lik, gated = random_case(rng, T, M)
        W, w0 = jpda(log_lik, gated, p)
        W_ref, w0_ref = brute_force_jpda(log_lik, gated, p)
        np.testing.assert_allclose(W, W_ref, rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(w0, w0_ref, rtol=1e-10, atol=1e-12)


def test_pda_equals_thesis_closed_form():
    rng = np.random.default_rng(12)
    log_lik, gated = random_case(rng, 3, 6)
    W, w0 = pda(log_lik, gated, P)
    for t in range(3):
        L = np.where(gated[t], np.exp(log_lik[t]) * P.pd / P.clutter_density, 0.0)  # (4.10)
        D = 1 - P.pd * P.pg + L.sum()
        np.testing.assert_allclose(W[t], L / D, rtol=1e-12, atol=1e-15)
        assert abs(w0[t] - (1 - P.pd * P.pg) / D) <= 1e-12


def test_single_track_jpda_with_pg_form_equals_pda():
    p = AssociationParams(pd=0.9, pg=0.99966, clutter_density=1e-2, use_pg=True)
    rng = np.random.default_rng(13)
    for M in range(0, 8):
        log_lik, gated = random_case(rng, 1, M, density=0.8)
        Wj, w0j = jpda(log_lik, gated, p)
        Wp, w0p = pda(log_lik, gated, p)
        np.testing.assert_allclose(Wj, Wp, rtol=0, atol=1e-12)
        np.testing.assert_allclose(w0j, w0p, rtol=0, atol=1e-12)


def test_single_track_thesis_form_differs_from_pda_by_the_pg_term():
    """Thesis-form JPDA (no P_G) is PDA with 1 - P_D in place of 1 - P_D P_G."""
    log_lik, gated = np.array([[-1.0, -2.0]]), np.array([[True, True]])
    W, w0 = jpda(log_lik, gated, P)
    L = np.exp(log_lik[0]) * P.pd / P.clutter_density
    np.testing.assert_allclose(W[0], L / (1 - P.pd + L.sum()), rtol=1e-12)
    assert abs(w0[0] - (1 - P.pd) / (1 - P.pd + L.sum())) <= 1e-12


def brute_force_gnn(log_lik, gated, p):
    T, M = log_lik.shape
    best = max(brute_force_events(log_lik, gated, p), key=lambda e: e[1])[0]
    W = np.zeros((T, M))
    for j, t in enumerate(best):
        if t >= 0:
            W[t, j] = 1.0
    return W, 1.0 - W.sum(axis=1)


def test_gnn_equals_brute_force_most_probable_event():
    rng = np.random.default_rng(14)
    for _ in range(60):
        T, M = rng.integers(1, 5), rng.integers(0, 6)
        log_lik, gated = random_case(rng, T, M, density=0.7)
        W, w0 = ASSOCIATORS["gnn"](log_lik, gated, P)
        W_ref, w0_ref = brute_force_gnn(log_lik, gated, P)
        np.testing.assert_array_equal(W, W_ref)
        np.testing.assert_array_equal(w0, w0_ref)


def test_nn_takes_each_tracks_most_likely_gated_measurement():
    log_lik = np.array([[-1.0, -0.5, -3.0], [-2.0, -0.1, -0.2], [0.0, 0.0, 0.0]])
    gated = np.array([[True, False, True], [False, True, True], [False, False, False]])
    W, w0 = ASSOCIATORS["nn"](log_lik, gated, P)
    np.testing.assert_array_equal(W, [[1, 0, 0], [0, 1, 0], [0, 0, 0]])
    np.testing.assert_array_equal(w0, [0, 0, 1])


def test_clusters_are_connected_components_whatever_the_order():
    gated = np.zeros((4, 5), dtype=bool)
    gated[0, [0, 1]] = gated[2, [1, 2]] = True  # tracks 0, 2 share measurement 1
    gated[1, 4] = True  # track 1 alone; track 3 has nothing
    got = sorted((tuple(t), tuple(m)) for t, m in clusters(gated))
    assert got == [((0, 2), (0, 1, 2)), ((1,), (4,))]
    perm_t, perm_m = np.array([3, 1, 0, 2]), np.array([4, 2, 0, 3, 1])
    got_p = sorted((tuple(sorted(perm_t[t])), tuple(sorted(perm_m[m])))
                   for t, m in clusters(gated[np.ix_(perm_t, perm_m)]))
    assert got_p == got


def test_jpda_overflow_raises_or_falls_back_to_pda_for_that_cluster_only():
    rng = np.random.default_rng(15)
    big = np.ones((3, 3), dtype=bool)  # 1 + 9 + 18 + 6 = 34 feasible events
    gated = np.zeros((4, 5), dtype=bool)
    gated[:3, :3] = big
    gated[3, 3:] = True  # a separate one-track cluster
    log_lik = rng.uniform(-3, 1, size=(4, 5))
    exact = jpda(log_lik, gated, P)
    with pytest.raises(JPDAOverflowError, match="max_events=33"):
        jpda(log_lik, gated, AssociationParams(pd=P.pd, pg=P.pg, clutter_density=P.clutter_density, max_events=33,
                                               on_overflow="raise"))
    at_cap = jpda(log_lik, gated, AssociationParams(pd=P.pd, pg=P.pg, clutter_density=P.clutter_density, max_events=34))
    np.testing.assert_allclose(at_cap[0], exact[0], atol=1e-15)
    small = AssociationParams(pd=P.pd, pg=P.pg, clutter_density=P.clutter_density, max_events=33)
    with pytest.warns(JPDAOverflowWarning, match="3 tracks and 3 measurements"):
        W, w0 = jpda(log_lik, gated, small)
    Wp, w0p = pda(log_lik[:3, :3], big, small)
    np.testing.assert_allclose(W[:3, :3], Wp, atol=1e-15)
    np.testing.assert_allclose(w0[:3], w0p, atol=1e-15)
    np.testing.assert_allclose(W[3], exact[0][3], atol=1e-15)  # the other cluster is still exact JPDA
    np.testing.assert_allclose(w0[3], exact[1][3], atol=1e-15)


def test_invalid_inputs_are_clear_errors():
    with pytest.raises(ValueError, match="same"):
        jpda(np.zeros((2, 3)), np.zeros((3, 2), dtype=bool), P)
    with pytest.raises(ValueError, match="bool"):
        jpda(np.zeros((2, 3)), np.zeros((2, 3)), P)
    with pytest.raises(ValueError, match="not finite"):
        pda(np.array([[np.nan]]), np.array([[True]]), P)
    with pytest.raises(ValueError, match="on_overflow"):
        AssociationParams(pd=0.9, pg=0.9, clutter_density=1e-2, on_overflow="ignore")
    with pytest.raises(ValueError, match="pd"):
        AssociationParams(pd=1.5, pg=0.9, clutter_density=1e-2)


# ---- properties over every registered associator -------------------------------------------------------------

@st.composite
def cases(draw):
    T = draw(st.integers(0, 4))
    M = draw(st.integers(0, 5))
    # continuous random log-likelihoods (seed and range from hypothesis): exact ties, which make the hard
    # associators' argmax order-dependent, have probability 0
    lo = draw(st.floats(-300.0, 0.0))
    width = draw(st.floats(0.01, 300.0))
    log_lik = np.random.default_rng(draw(st.integers(0, 2**32 - 1))).uniform(lo, lo + width, size=(T, M))
    gated = draw(arrays(np.bool_, (T, M)))
    pd = draw(st.sampled_from([0.5, 0.9, 0.99]))
    use_pg = draw(st.booleans())
    perm_t = draw(st.permutations(range(T)))
    perm_m = draw(st.permutations(range(M)))
    return log_lik, gated, AssociationParams(pd=pd, pg=0.99966, clutter_density=1e-2, use_pg=use_pg), perm_t, perm_m


@pytest.mark.parametrize("name", sorted(ASSOCIATORS))
@settings(max_examples=60, deadline=None)
@given(case=cases())
def test_association_properties(name, case):
    log_lik, gated, p, perm_t, perm_m = case
    fn = ASSOCIATORS[name]
    T, M = log_lik.shape
    W, w0 = fn(log_lik, gated, p)
    assert W.shape == (T, M) and w0.shape == (T,)
    np.testing.assert_allclose(W.sum(axis=1) + w0, 1.0, rtol=0, atol=1e-12)
    assert np.all((W >= 0) & (W <= 1)) and np.all((w0 >= 0) & (w0 <= 1 + 1e-15))
    assert np.all(W[~gated] == 0.0)
    pt, pm = np.array(perm_t, dtype=int), np.array(perm_m, dtype=int)
    Wp, w0p = fn(log_lik[np.ix_(pt, pm)], gated[np.ix_(pt, pm)], p)
    np.testing.assert_allclose(Wp, W[np.ix_(pt, pm)], rtol=0, atol=1e-12)
    np.testing.assert_allclose(w0p, w0[pt], rtol=0, atol=1e-12)
