"""trackers.association.logsum.logsumexp equals scipy.special.logsumexp bit for bit (values, NaNs, shapes)."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.special import logsumexp as scipy_logsumexp

from roadtrack.trackers.association.logsum import logsumexp

SPECIAL = [-np.inf, np.inf, np.nan, 0.0, 700.0, -745.0, 1e-300]


@st.composite
def arrays(draw):
    shape = tuple(draw(st.lists(st.integers(0, 6), min_size=1, max_size=3)))
    rng = np.random.default_rng(draw(st.integers(0, 2 ** 32 - 1)))
    a = rng.normal(0.0, draw(st.sampled_from([1e-3, 1.0, 30.0, 400.0])), shape)
    if a.size:
        kind = rng.random(shape)
        a[kind < draw(st.sampled_from([0.0, 0.3, 0.9, 1.0]))] = -np.inf  # the associators' masked pairs
        a[(kind > 0.93) & (kind < 0.97)] = rng.choice(SPECIAL, int(((kind > 0.93) & (kind < 0.97)).sum()))
        if draw(st.booleans()):
            a.flat[-1] = a.flat[0]  # a tie at the maximum
    axis = draw(st.sampled_from([None] + list(range(-len(shape), len(shape)))))
    return a, axis, draw(st.booleans())


@settings(max_examples=400, deadline=None)
@given(arrays())
def test_logsumexp_is_scipys_bit_for_bit(case):
    a, axis, keepdims = case
    try:
        want = scipy_logsumexp(a, axis=axis, keepdims=keepdims)
    except IndexError:  # scipy's own limit (an empty array over several axes): the same error
        with pytest.raises(IndexError):
            logsumexp(a, axis=axis, keepdims=keepdims)
        return
    got = logsumexp(a, axis=axis, keepdims=keepdims)
    assert np.shape(got) == np.shape(want) and type(got) is type(want)
    np.testing.assert_array_equal(got, want)  # NaN where scipy has NaN, equal (==) elsewhere
    assert np.array_equal(np.signbit(got), np.signbit(want))


def test_the_associators_rows():
    """(T, 1 + M) rows of a miss term and gated log-likelihoods (-inf off the gate), as pda_log_denominator has."""
    rng = np.random.default_rng(1)
    a = np.where(rng.random((60, 71)) < 0.9, -np.inf, rng.normal(0, 20, (60, 71)))
    a[:, 0] = np.log1p(-0.9 * 0.9997)
    a[5] = -np.inf
    for axis, keepdims in ((1, False), (1, True), (None, False)):
        np.testing.assert_array_equal(logsumexp(a, axis, keepdims), scipy_logsumexp(a, axis=axis, keepdims=keepdims))
    assert logsumexp(a[5], 0) == -np.inf
