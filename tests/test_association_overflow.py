"""Association that never dies of density (issue 30): a JPDA cluster over its exact budget falls back for that
cluster only (k-best events by default, per-track PDA, or an error with on_overflow = "raise"), and the fallback
is flagged per track and counted per cluster."""
import numpy as np
import pytest

from roadtrack.trackers import JPDAOverflowError, JPDAOverflowWarning
from roadtrack.trackers.association.jpda import (DEFAULT_MAX_NODES, FALLBACK_DIAGNOSTIC, fallback_clusters, jpda,
                                       jpda_fallbacks)
from roadtrack.trackers.association.kbest import k_best_marginals
from roadtrack.trackers.association.params import AssociationParams, joint_event_terms
from roadtrack.trackers.association.pda import pda
from roadtrack.trackers.association.roles import ASSOCIATORS, JPDAParams
from roadtrack.trackers.params import load

from test_trackers_association import scan_input  # tests/ is on sys.path (rootdir conftest)

P = AssociationParams(pd=0.9, pg=0.9997, clutter_density=1e-2)


def dense_scan(rng, T=22, M=24):
    """A T x M cluster with every pair gated (EHM frontier min(T, M) = 22: 2^22 nodes, over the default
    max_nodes = 2^20) and a separate 2 x 2 cluster; log-likelihoods uniform in [-4, 0]."""
    log_lik = rng.uniform(-4.0, 0.0, (T + 2, M + 2))
    gated = np.zeros((T + 2, M + 2), dtype=bool)
    gated[:T, :M] = True
    gated[T:, M:] = True
    return log_lik, gated, np.arange(T), np.arange(M)


def test_ehm_over_its_budget_falls_back_to_k_best_for_that_cluster_only():
    rng = np.random.default_rng(30)
    log_lik, gated, ts, ms = dense_scan(rng)
    W, w0, fell = jpda_fallbacks(log_lik, gated, P, k=50)  # default method "ehm", default max_nodes
    assert DEFAULT_MAX_NODES == 1 << 20
    np.testing.assert_array_equal(fell, np.arange(len(fell)) < ts.size)
    a, b = joint_event_terms(log_lik[np.ix_(ts, ms)], P)
    Wk, w0k = k_best_marginals(a, b, gated[np.ix_(ts, ms)], 50)
    np.testing.assert_allclose(W[np.ix_(ts, ms)], Wk, rtol=0, atol=1e-15)
    np.testing.assert_allclose(w0[ts], w0k, rtol=0, atol=1e-15)
    np.testing.assert_allclose(W.sum(axis=1) + w0, 1.0, rtol=0, atol=1e-12)
    small = jpda(log_lik[ts.size:, ms.size:], gated[ts.size:, ms.size:], P)  # the other cluster: still exact
    np.testing.assert_allclose(W[ts.size:, ms.size:], small[0], rtol=0, atol=1e-15)
    np.testing.assert_allclose(w0[ts.size:], small[1], rtol=0, atol=1e-15)
    assert fallback_clusters(gated, fell) == 1


def test_on_overflow_raise_and_pda_stay_available():
    rng = np.random.default_rng(31)
    log_lik, gated, ts, ms = dense_scan(rng, T=8, M=9)
    with pytest.raises(JPDAOverflowError, match=r"^JPDA \(ehm\) cluster of 9x8 .*max_nodes=64[^\n]*$"):
        jpda(log_lik, gated, AssociationParams(pd=0.9, pg=0.9997, clutter_density=1e-2, on_overflow="raise"),
             max_nodes=64)
    as_pda = AssociationParams(pd=0.9, pg=0.9997, clutter_density=1e-2, on_overflow="pda")
    with pytest.warns(JPDAOverflowWarning, match="8 tracks and 9 measurements exceeds max_nodes=64"):
        W, w0, fell = jpda_fallbacks(log_lik, gated, as_pda, max_nodes=64)
    Wp, w0p = pda(log_lik[np.ix_(ts, ms)], gated[np.ix_(ts, ms)], as_pda)
    np.testing.assert_allclose(W[np.ix_(ts, ms)], Wp, rtol=0, atol=1e-15)
    np.testing.assert_allclose(w0[ts], w0p, rtol=0, atol=1e-15)
    assert fell[:ts.size].all() and not fell[ts.size:].any()


def test_enumerate_over_max_events_also_falls_back_to_k_best_by_default():
    rng = np.random.default_rng(32)
    log_lik, gated, ts, ms = dense_scan(rng, T=5, M=6)
    capped = AssociationParams(pd=0.9, pg=0.9997, clutter_density=1e-2, max_events=100)
    W, w0, fell = jpda_fallbacks(log_lik, gated, capped, method="enumerate", k=7)
    Wk, w0k = jpda(log_lik, gated, capped, method="k_best", k=7)
    np.testing.assert_allclose(W[np.ix_(ts, ms)], Wk[np.ix_(ts, ms)], rtol=0, atol=1e-15)
    exact = jpda(log_lik, gated, capped, method="ehm")
    assert np.abs(W[np.ix_(ts, ms)] - exact[0][np.ix_(ts, ms)]).max() > 1e-3  # k = 7 of the 4051 events: approximate
    assert fell.sum() == ts.size


def test_the_registry_reports_the_fallback_per_track_and_the_clusters_are_counted():
    rng = np.random.default_rng(33)
    inp = scan_input(rng, 12, 14, 1e4, pd_choices=(0.9,))  # a huge gate: one cluster of every track
    p = load(JPDAParams, {"max_nodes": 16, "k": 5}, "associator")
    W, w0, info = ASSOCIATORS["jpda"].run(inp, p)
    flags = info[FALLBACK_DIAGNOSTIC]
    assert flags.shape == (12,) and set(np.unique(flags[np.isfinite(flags)])) == {1.0}
    assert fallback_clusters(inp.gated, flags) == 1
    W_raise = load(JPDAParams, {"max_nodes": 16, "on_overflow": "raise"}, "associator")
    with pytest.raises(JPDAOverflowError):
        ASSOCIATORS["jpda"].run(inp, W_raise)
    exact = ASSOCIATORS["jpda"].run(inp, load(JPDAParams, {}, "associator"))
    assert np.isnan(exact[2][FALLBACK_DIAGNOSTIC]).all()


def test_fallback_clusters_counts_components_and_rejects_bad_shapes():
    gated = np.zeros((5, 4), dtype=bool)
    gated[0:2, 0] = gated[2:4, 1:3] = gated[4, 3] = True  # clusters {0, 1}, {2, 3}, {4}
    assert fallback_clusters(gated, np.array([1, 1, 1, np.nan, np.nan])) == 2
    assert fallback_clusters(gated, np.array([False, True, False, False, True])) == 2
    assert fallback_clusters(gated, np.full(5, np.nan)) == 0
    with pytest.raises(ValueError, match="one flag per track"):
        fallback_clusters(gated, np.ones(4))
