"""Associators against independent brute force, PDA closed form, hand-worked AN (seed 001) and APDA (thesis
ch. 5) cases, the registry contract with hypothesis, and the thesis §5.6.1 APDA claim on testbed.reproduce.thesis.synthetic.
Claims tests assert what does happen with the stated parameters."""

import dataclasses
import itertools
import math
import os

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from roadtrack.testbed.reproduce.thesis import synthetic as sy
from roadtrack.trackers import (ASSOCIATORS, AssociationInput, AssociationParams, JPDAOverflowError, JPDAOverflowWarning,
                      global_nearest_neighbour, jpda, nearest_neighbour, pda)
from roadtrack.trackers.association.an import all_neighbours
from roadtrack.trackers.association.jpda import clusters
from roadtrack.trackers.association.roles import ANParams, APDAParams, JPDAParams
from roadtrack.trackers.filters import make_filter
from roadtrack.trackers.gating import gate_probability, mahalanobis2_and_log_gaussian
from roadtrack.trackers.params import load
from roadtrack.trackers.tracker import gate_volume

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


@pytest.mark.parametrize("kind, table", [("pda", {}), ("jpda", {"use_pg": True}), ("apda", {})])
@pytest.mark.parametrize("pg", [None, 0.5, 1.0])
def test_gate_probability_reaches_the_weights_and_the_score_by_hand(kind, table, pg):
    """One confirmed track at x = 0, P = I, dt = 0 (no process noise), sigma_w = 1: S = 2 I; one measurement at
    (1, 0): d2 = 1/2, N = exp(-1/4) / (4 pi), L = P_D N / lambda = 0.8 N / 0.1 = 2 exp(-1/4) / pi = 0.49580.
    beta0 = (1 - P_D P_G) / (1 - P_D P_G + L) (4.10)-(4.13) and the score increment ln(1 - P_D P_G + L) (1.35),
    with P_G = pg, or 1 - exp(-8) = 0.99966 (the alpha = 16 gate's chi-square mass) when pg is None. The
    single-track P_D P_G-form JPDA is the PDA; APDA is the PDA when no layer is given (kf: nothing chatters)."""
    from roadtrack.trackers import make_tracker
    from roadtrack.trackers.state import FilterState
    from roadtrack.trackers.tracker import Track

    extra = {} if pg is None else {"pg": pg}
    trk = make_tracker(f"{kind}-kf", sigma_w=1.0, pd=0.8, clutter_density=0.1, associator={**table, **extra})
    P_G = 1.0 - math.exp(-8.0) if pg is None else pg
    assert trk.pg == pytest.approx(P_G, rel=1e-15)
    track = Track(id=1, state=FilterState(x=np.zeros(4), P=np.eye(4), e_post=np.zeros(2)), score=5.0, max_score=5.0,
                  confirmed=True, age=5, hits=5, misses_in_a_row=0)
    res = trk.step((track,), np.array([[1.0, 0.0]]), 0.0, 2)
    L = 2.0 * math.exp(-0.25) / math.pi
    miss = 1.0 - 0.8 * P_G
    assert res.info.w0[0] == pytest.approx(miss / (miss + L), rel=1e-12)
    assert res.info.W[0, 0] == pytest.approx(L / (miss + L), rel=1e-12)
    assert res.info.diagnostics["score"][0] - 5.0 == pytest.approx(math.log(miss + L), rel=1e-12)


@pytest.mark.parametrize("value, words", [(0.0, "0.0 is not allowed; must be in (0, 1]"),
                                          (1.5, "1.5 is not allowed; must be in (0, 1]"),
                                          ("high", "expected float or NoneType, got 'high'")])
def test_a_bad_gate_probability_is_a_one_line_error(value, words):
    from roadtrack.trackers import ParamError, make_tracker

    with pytest.raises(ParamError) as info:
        make_tracker("jpda-kf", associator={"pg": value})
    assert str(info.value) == f"associator.pg: {words}"


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
        W, w0 = global_nearest_neighbour(log_lik, gated, P)
        W_ref, w0_ref = brute_force_gnn(log_lik, gated, P)
        np.testing.assert_array_equal(W, W_ref)
        np.testing.assert_array_equal(w0, w0_ref)


def test_nn_takes_each_tracks_most_likely_gated_measurement():
    log_lik = np.array([[-1.0, -0.5, -3.0], [-2.0, -0.1, -0.2], [0.0, 0.0, 0.0]])
    gated = np.array([[True, False, True], [False, True, True], [False, False, False]])
    W, w0 = nearest_neighbour(log_lik, gated, P)
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
    """max_events / on_overflow guard method 'enumerate' (the default 'ehm' has its own guard)."""
    rng = np.random.default_rng(15)
    big = np.ones((3, 3), dtype=bool)  # 1 + 9 + 18 + 6 = 34 feasible events
    gated = np.zeros((4, 5), dtype=bool)
    gated[:3, :3] = big
    gated[3, 3:] = True  # a separate one-track cluster
    log_lik = rng.uniform(-3, 1, size=(4, 5))
    exact = jpda(log_lik, gated, P, method="enumerate")
    with pytest.raises(JPDAOverflowError, match="max_events=33"):
        jpda(log_lik, gated, AssociationParams(pd=P.pd, pg=P.pg, clutter_density=P.clutter_density, max_events=33,
                                               on_overflow="raise"), method="enumerate")
    at_cap = jpda(log_lik, gated, AssociationParams(pd=P.pd, pg=P.pg, clutter_density=P.clutter_density, max_events=34),
                  method="enumerate")
    np.testing.assert_allclose(at_cap[0], exact[0], atol=1e-15)
    small = AssociationParams(pd=P.pd, pg=P.pg, clutter_density=P.clutter_density, max_events=33, on_overflow="pda")
    with pytest.warns(JPDAOverflowWarning, match="3 tracks and 3 measurements"):
        W, w0 = jpda(log_lik, gated, small, method="enumerate")
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

def scan_input(rng, T, M, alpha, pd_choices=(0.0, 0.5, 0.9, 1.0)):
    """A geometric scan: T predicted measurements and M measurements in a 10 m square, random SPD S per track,
    the innovations, d2, log N and gate flags derived from them, per-track P_D, boundary layers (NaN rows:
    filters without one)."""
    z_hat, Z = rng.uniform(0, 10, (T, 2)), rng.uniform(0, 10, (M, 2))
    L = rng.normal(size=(T, 2, 2))
    S = L @ L.transpose(0, 2, 1) + rng.uniform(0.3, 3.0, (T, 1, 1)) * np.eye(2)
    nu = Z[None, :, :] - z_hat[:, None, :]
    d2, log_lik = mahalanobis2_and_log_gaussian(nu, S)
    layers = np.where(rng.random((T, 1)) < 0.5, np.nan, rng.uniform(0.0, 3.0, (T, 2)))
    return AssociationInput(log_lik=log_lik, gated=d2 <= alpha, d2=d2, nu=nu, S=S,
                            pd=rng.choice(pd_choices, size=T), pg=gate_probability(alpha, 2),
                            gate_volume=gate_volume(S, alpha) if T else np.zeros(0), layers=layers)


def permuted(inp, pt, pm):
    return AssociationInput(log_lik=inp.log_lik[np.ix_(pt, pm)], gated=inp.gated[np.ix_(pt, pm)],
                            d2=inp.d2[np.ix_(pt, pm)], nu=inp.nu[pt][:, pm], S=inp.S[pt], pd=inp.pd[pt], pg=inp.pg,
                            gate_volume=inp.gate_volume[pt], layers=inp.layers[pt])


def registry_params(name, alpha, use_pg, variant):
    """Default parameters of associator `name` with the gate alpha, the P_G form and one of its own choices."""
    kind = ASSOCIATORS[name]
    data = {"gate_alpha": alpha, "use_pg": use_pg}
    choices = {f.name: f.metadata["choices"] for f in dataclasses.fields(kind.params) if "choices" in f.metadata}
    for key, allowed in sorted(choices.items()):
        data[key] = allowed[variant % len(allowed)]
    return load(kind.params, data, "associator")


@st.composite
def scan_cases(draw):
    T, M = draw(st.integers(0, 5)), draw(st.integers(0, 6))
    alpha = draw(st.sampled_from([4.0, 16.0, 36.0]))
    inp = scan_input(np.random.default_rng(draw(st.integers(0, 2**32 - 1))), T, M, alpha)
    return (inp, alpha, draw(st.booleans()), draw(st.integers(0, 5)), draw(st.permutations(range(T))),
            draw(st.permutations(range(M))))


@pytest.mark.parametrize("name", sorted(ASSOCIATORS))
@settings(max_examples=60, deadline=None)
@given(case=scan_cases())
def test_association_contract(name, case):
    """Every registered associator: W (T, M) and w0 (T,) in [0, 1], rows of [W, w0] summing to 1 (1e-12),
    W = 0 where not gated, per-track diagnostics (T,), and the same answer for permuted tracks and
    measurements (1e-12). Continuous random geometry: exact ties (order-dependent argmax) have probability 0."""
    inp, alpha, use_pg, variant, perm_t, perm_m = case
    kind = ASSOCIATORS[name]
    p = registry_params(name, alpha, use_pg, variant)
    T, M = inp.gated.shape
    out = kind.run(inp, p)
    W, w0 = out[0], out[1]
    info = out[2] if len(out) > 2 else {}
    assert W.shape == (T, M) and w0.shape == (T,)
    np.testing.assert_allclose(W.sum(axis=1) + w0, 1.0, rtol=0, atol=1e-12)
    assert np.all((W >= 0) & (W <= 1)) and np.all((w0 >= 0) & (w0 <= 1 + 1e-15))
    assert np.all(W[~inp.gated] == 0.0)
    assert all(np.shape(v) == (T,) for v in info.values())
    pt, pm = np.array(perm_t, dtype=int), np.array(perm_m, dtype=int)
    out_p = kind.run(permuted(inp, pt, pm), p)
    np.testing.assert_allclose(out_p[0], W[np.ix_(pt, pm)], rtol=0, atol=1e-12)
    np.testing.assert_allclose(out_p[1], w0[pt], rtol=0, atol=1e-12)
    for key, v in info.items():
        np.testing.assert_allclose(out_p[2][key], np.asarray(v)[pt], rtol=0, atol=1e-12)


@pytest.mark.parametrize("method", ["ehm", "enumerate", "k_best"])
def test_registry_jpda_methods_agree_with_the_plain_function(method):
    rng = np.random.default_rng(16)
    for _ in range(20):
        inp = scan_input(rng, 5, 7, 16.0, pd_choices=(0.7, 0.9))
        p = load(JPDAParams, {"method": method, "k": 5}, "associator")
        W, w0, info = ASSOCIATORS["jpda"].run(inp, p)
        assert np.isnan(info["jpda_fallback"]).all()  # small clusters: no fallback
        Wr, w0r = jpda(inp.log_lik, inp.gated, p.problem(inp.pg), inp.pd, method=method, k=5)
        np.testing.assert_array_equal(W, Wr)
        np.testing.assert_array_equal(w0, w0r)


# ---- all neighbours, seed 001 (22)-(23) -------------------------------------------------------------------------

def hand_input(nu, S, gated, layers=None, alpha=16.0, pd=0.9):
    """One-track AssociationInput from innovations nu (M, 2) and S (2, 2)."""
    nu = np.asarray(nu, dtype=np.float64)[None]
    S = np.asarray(S, dtype=np.float64)[None]
    d2, log_lik = mahalanobis2_and_log_gaussian(nu, S)
    return AssociationInput(log_lik=log_lik, gated=np.asarray(gated)[None], d2=d2, nu=nu, S=S, pd=np.array([pd]),
                            pg=gate_probability(alpha, 2), gate_volume=gate_volume(S, alpha),
                            layers=np.full((1, 2), np.nan) if layers is None else np.asarray(layers, float)[None])


def run_an(inp, distance="euclidean"):
    return ASSOCIATORS["an"].run(inp, load(ANParams, {"distance": distance}, "associator"))


def test_an_weights_follow_the_linear_distance_formula_by_hand():
    """Seed 001 (22): Euclidean distances 1, 2, 3 (sum 6, N = 3) give (1 - D/6) / 2 = 5/12, 4/12, 3/12; the
    fourth measurement is outside the gate. With S = 4 I the Mahalanobis distances are D / 2: same weights;
    squared (1/4, 1, 9/4, sum 7/2): (1 - d2 / 3.5) / 2 = 13/28, 5/14, 5/28."""
    nu, S, gated = [[1.0, 0.0], [0.0, -2.0], [-1.8, 2.4], [9.0, 0.0]], 4.0 * np.eye(2), [True, True, True, False]
    W, w0 = run_an(hand_input(nu, S, gated))
    np.testing.assert_allclose(W[0], [5 / 12, 4 / 12, 3 / 12, 0.0], rtol=0, atol=1e-15)
    assert w0[0] == 0.0
    np.testing.assert_allclose(run_an(hand_input(nu, S, gated), "mahalanobis")[0][0], W[0], rtol=0, atol=1e-15)
    np.testing.assert_allclose(run_an(hand_input(nu, S, gated), "mahalanobis2")[0][0], [13 / 28, 5 / 14, 5 / 28, 0],
                               rtol=0, atol=1e-15)


def test_an_special_cases_two_one_none_and_zero_distances():
    """N = 2: inverse-distance P_1 = D_2 / (D_1 + D_2) = 3/4; N = 1: weight 1; N = 0: coast (w0 = 1);
    all distances 0: equal weights 1/N [D]; the cap 1/(N - 1) holds at zero distance."""
    W, w0 = all_neighbours(np.array([[1.0, 3.0], [2.0, 5.0], [1.0, 1.0], [0.0, 0.0]]),
                           np.array([[True, True], [False, True], [False, False], [True, True]]))
    np.testing.assert_allclose(W, [[0.75, 0.25], [0.0, 1.0], [0.0, 0.0], [0.5, 0.5]], rtol=0, atol=1e-15)
    np.testing.assert_array_equal(w0, [0.0, 0.0, 1.0, 0.0])
    W, _ = all_neighbours(np.array([[0.0, 4.0, 6.0]]), np.ones((1, 3), dtype=bool))
    np.testing.assert_allclose(W[0], [0.5, 0.3, 0.2], rtol=0, atol=1e-15)  # nearest capped at 1/(N-1) = 1/2


# ---- APDA, thesis (5.37)-(5.54) ---------------------------------------------------------------------------------

def run_apda(inp, **kw):
    return ASSOCIATORS["apda"].run(inp, load(APDAParams, kw, "associator"))


def pda_of(inp):
    return pda(inp.log_lik, inp.gated, AssociationParams(pd=float(inp.pd[0]), pg=inp.pg, clutter_density=1e-2))


def test_apda_equals_pda_when_nothing_chatters():
    """§5.5.3 (5.63): a box of 20 m contains the gate (no measurement can chatter); §6.5: a 2 m box inside the
    gate with every validated measurement inside it. Both: the PDA weights of (4.13), exactly, and no activity."""
    rng = np.random.default_rng(17)
    S = np.array([[2.0, 0.5], [0.5, 1.0]])
    nu = rng.uniform(-1.9, 1.9, (5, 2))
    for layers, psi_max in ((None, 20.0), (None, 2.0), ([2.0, 2.0], 0.1)):
        inp = hand_input(nu, S, np.ones(5, dtype=bool), layers=layers)
        for form in ("consistent", "thesis"):
            W, w0, info = run_apda(inp, psi_max=psi_max, form=form)
            Wp, w0p = pda_of(inp)
            np.testing.assert_array_equal(W, Wp)
            np.testing.assert_array_equal(w0, w0p)
            assert info["apda_active"][0] == 0.0 and info["chattering"][0] == 0.0


def test_apda_hand_worked_chattering_case_in_both_forms():
    """S = [[2, .5], [.5, 1]], layer psi = (1, 0.8) from the filter, alpha = 16, P_D = 0.9, lambda = 1e-2.
    e1 = (0.5, -0.3) is inside the box (C1 = 0); e2 = (2, 1.5) chatters with C2 = (1, 0.7) (5.37).
    Half-normal (5.42) with D S D = 2 diag(diag S) - S:
        N_h(c) = k / sqrt|S| (exp(-c' S^-1 c / 2) + exp(-c' (D S D)^-1 c / 2)), k = 1/(4 pi) printed, 1/pi consistent;
    f_i = N(e_i; 0, S) N_h(C_i) and a = lambda P_G (1 - P_D P_G) / ([P_D] (V - 4 psi_1 psi_2)) (5.54)."""
    S = np.array([[2.0, 0.5], [0.5, 1.0]])
    e = np.array([[0.5, -0.3], [2.0, 1.5]])
    C = np.array([[0.0, 0.0], [1.0, 0.7]])
    inp = hand_input(e, S, [True, True], layers=[1.0, 0.8])
    det = 2.0 * 1.0 - 0.25
    Si, DSDi = np.linalg.inv(S), np.linalg.inv(2 * np.diag(np.diag(S)) - S)
    gauss = np.array([math.exp(-0.5 * x @ Si @ x) / (2 * math.pi * math.sqrt(det)) for x in e])
    shape = np.array([math.exp(-0.5 * c @ Si @ c) + math.exp(-0.5 * c @ DSDi @ c) for c in C])
    pg, pd, lam = 1 - math.exp(-8.0), 0.9, 1e-2
    v_c = math.pi * 16.0 * math.sqrt(det) - 4 * 1.0 * 0.8
    for form, k, a in (("thesis", 1 / (4 * math.pi), lam * pg * (1 - pd * pg) / v_c),
                       ("consistent", 1 / math.pi, lam * pg * (1 - pd * pg) / (pd * v_c))):
        f = gauss * k / math.sqrt(det) * shape
        W, w0, info = run_apda(inp, form=form, clutter_density=lam, pd=pd)
        np.testing.assert_allclose(W[0], f / (a + f.sum()), rtol=1e-12, atol=0)  # (5.53)
        np.testing.assert_allclose(w0[0], a / (a + f.sum()), rtol=1e-12, atol=0)
        assert info["apda_active"][0] == 1.0 and info["chattering_n"][0] == 1.0
        assert abs(info["chattering"][0] - math.hypot(1.0, 0.7)) <= 1e-12
    Wp, _ = pda_of(inp)
    assert W[0, 0] / W[0, 1] > Wp[0, 0] / Wp[0, 1]  # the measurement inside the layer gains weight (§5.5.3)


def test_apda_falls_back_to_pda_when_the_box_fills_the_gate_volume_or_pd_is_zero():
    """§6.5: V_c = V - 2^m det(Psi) <= 0 (a 9.9 m x 0.1 m box ... here 2 psi = (12, 12) against V = 16 pi
    sqrt|S| = 66.5 m^2) while a measurement still chatters along its long axis; and P_D = 0."""
    S = np.array([[2.0, 0.5], [0.5, 1.0]])
    e = np.array([[0.0, 3.5], [0.5, 0.2]])  # |e_2| = 3.5 > psi = ... see layers
    inp = hand_input(e, S, [True, True], layers=[6.0, 3.0])  # box 12 x 6 = 72 > V = 66.5; C1 = (0, 0.5)
    W, w0, info = run_apda(inp)
    Wp, w0p = pda_of(inp)
    np.testing.assert_array_equal(W, Wp)
    assert info["chattering_n"][0] == 1.0 and info["apda_active"][0] == 0.0
    inp0 = hand_input(e, S, [True, True], layers=[1.0, 1.0], pd=0.0)
    W, w0, info = run_apda(inp0)
    np.testing.assert_array_equal(W, 0.0)
    assert w0[0] == 1.0 and info["apda_active"][0] == 0.0


# ---- thesis §5.6.1 claim: RMSE APDA-SVSF < PDA-SVSF < PDA-KF at lambda = 1 / m^2 ---------------------------------

FULL = bool(os.environ.get("ROADTRACK_FULL"))


def s51_rmse(n_runs, seed):
    """Position RMSE [m] of APDA-SVSF, PDA-SVSF (= PDA-GVBL-SVSF, thesis ch. 5) and PDA-KF over the same
    n_runs runs of the thesis Table 5.1 target. Stated: x0 = (1 m, 25 m, 33 m/s, 1 m/s), Ts = 0.1 s, 30 s of
    NCV / CT 0.2 rad/s / NCV / CT 0.4 / NCV / CT 0.2 (70, 70, 30, 30, 40, 60 scans), filter sigma_v^2 = 36
    ("62" read 6^2), sigma_w^2 = 1 m^2, lambda = 1 / m^2. Not stated, chosen here [D]: P_D = 0.9, alpha = 16,
    gamma = 0.1 (the ch. 4 value), psi_max = 2 sigma_w (the ch. 4 value, 20 m, would make APDA equal PDA), truth white acceleration 0.5 m/s^2 on the NCV pieces, CT turns counter-clockwise,
    clutter uniform in a 20 m square centred on the true target (testbed.reproduce.thesis.synthetic default), estimate started
    at the truth with the two-point P0. The APDA layer is the GVBL filter's (min(|Psi_z| of the previous
    update, psi_max)); APDA in its default ("consistent") form."""
    segments = (sy.Segment(70), sy.Segment(70, omega=0.2), sy.Segment(30), sy.Segment(30, omega=0.4),
                sy.Segment(40), sy.Segment(60, omega=0.2))
    scn = sy.Scenario(x0=(1.0, 25.0, 33.0, 1.0), segments=segments, dt=0.1, sigma_v=0.5, sigma_w=1.0, pd=0.9,
                      clutter_density=1.0)
    kf = make_filter("kf", sigma_v=6.0, sigma_w=1.0)
    svsf = make_filter("gvbl-svsf", sigma_v=6.0, sigma_w=1.0, gamma=0.1, psi_max=2.0)
    pda_runs = sy.monte_carlo(scn, {"pda-kf": kf, "pda-svsf": svsf}, n_runs, seed, associator="pda")
    apda_runs = sy.monte_carlo(scn, {"apda-svsf": svsf}, n_runs, seed, associator="apda")
    runs = {**pda_runs, **apda_runs}
    return {name: math.hypot(*mc.rmse()[:2]) for name, mc in runs.items()}


def test_claim_s51_apda_svsf_best_is_not_reproduced_at_the_printed_clutter_density():
    """Thesis §5.6.1 / Table 5.2: at lambda = 1 / m^2 all three methods track and APDA-SVSF < PDA-SVSF < PDA-KF
    in RMSE. Measured (8 runs, seed 2; seeds 1-5 alike): every method loses the target, its error being that of a
    clutter point of the 20 m window (uniform: 8.2 m RMS): PDA-KF 8.35 m, PDA-SVSF 8.31 m, APDA-SVSF 10.63 m
    (10.4-38 m over seeds 1-5, the worst each time: preferring measurements inside the 2 m layer makes the
    track stick to clutter near the prediction). So neither the tracking nor the ordering comes out
    (~300 clutter points fall in a gate at this density). Asserted: all RMSE
    > 5 sigma_w; APDA-SVSF above PDA-SVSF by more than 1 m; the two PDA filters within 0.5 m of each other."""
    rmse = s51_rmse(8, 2)
    assert min(rmse.values()) > 5.0, rmse
    assert rmse["apda-svsf"] > rmse["pda-svsf"] + 1.0, rmse
    assert abs(rmse["pda-svsf"] - rmse["pda-kf"]) < 0.5, rmse


@pytest.mark.slow
@pytest.mark.skipif(not FULL, reason="500-run Monte Carlo: set ROADTRACK_FULL=1")
def test_claim_s51_500_runs():
    """As the reduced test over the thesis's 500 runs (seed 5100; about 9 min on a loaded 2-core machine).
    Measured: PDA-KF 8.33 m, PDA-SVSF 8.43 m, APDA-SVSF 26.0 m."""
    rmse = s51_rmse(500, 5100)
    assert min(rmse.values()) > 5.0, rmse
    assert rmse["apda-svsf"] > rmse["pda-svsf"] + 1.0, rmse
    assert abs(rmse["pda-svsf"] - rmse["pda-kf"]) < 0.5, rmse
