"""The stacked rows the batched filters hand on within a scan (trackers.state.StateRows, the IMM's IMMRows) are
exactly the fields of the states they carry, and reading them changes no output bit (issue 30: the tracker's
outputs must stay bit for bit those of the per-list stacking)."""

import numpy as np
import pytest

from roadtrack.trackers import make_filter
from roadtrack.trackers.filters.imm import IMMRows
from roadtrack.trackers.state import StateRows, rows_of, take_rows

T, M = 12, 7


def _states(flt, rng):
    x0 = np.c_[rng.uniform(0, 100, T), rng.uniform(-8, 8, T), rng.uniform(15, 30, T), rng.normal(0, 1, T)]
    return [flt.initial_state(x, np.diag([0.5, 0.5, 4.0, 4.0])) for x in x0]


def _weights(rng):
    W = rng.dirichlet(np.ones(M + 1), size=T)
    W[:3] = 0.0  # three tracks missed: w0 = 1
    W[:3, 0] = 1.0
    return W[:, 1:], W[:, 0]


def _assert_rows(states, fields=("x", "P", "e_post")):
    """Every carried array equals the stack of the states' fields, bit for bit."""
    assert type(states) is StateRows
    for name in fields:
        carried = getattr(states, name)
        if carried is not None:
            np.testing.assert_array_equal(carried, np.array([getattr(s, name) for s in states]))


def test_kf_predict_shift_and_update_carry_their_rows_exactly():
    rng = np.random.default_rng(3)
    kf = make_filter("kf", sigma_v=1.0, sigma_w=0.3)
    pred = kf.predict_many(_states(kf, rng), 0.1)
    _assert_rows(pred)
    shifted = kf.shift_many(pred, rng.normal(0, 0.05, (T, 4)) * (rng.random((T, 1)) < 0.5), spread=True)
    _assert_rows(shifted)
    z, S = kf.predicted_measurements(shifted)
    nu = rng.normal(0, 0.5, (T, M, 2))
    W, w0 = _weights(rng)
    carried = kf.update_many(shifted, nu, W, w0)
    plain = kf.update_many(list(shifted), nu, W, w0)  # a plain list: every field stacked from the states
    for a, b in zip(carried, plain):
        for name in ("x", "P", "e_post"):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    np.testing.assert_array_equal(z, kf.predicted_measurements(list(shifted))[0])
    np.testing.assert_array_equal(S, kf.predicted_measurements(list(shifted))[1])


def test_rows_of_and_take_rows_read_the_rows_and_fall_back_to_stacking():
    rng = np.random.default_rng(5)
    kf = make_filter("kf", sigma_v=1.0, sigma_w=0.3)
    pred = kf.predict_many(_states(kf, rng), 0.1)
    idx = np.array([7, 1, 4])
    sub = take_rows(pred, idx)
    _assert_rows(sub, ("x", "P"))
    assert [id(s) for s in sub] == [id(pred[t]) for t in idx]
    np.testing.assert_array_equal(rows_of(pred, "x", idx), rows_of(list(pred), "x", idx))
    assert type(pred[2:]) is list and type(list(pred)) is list  # a slice or copy carries nothing


@pytest.mark.parametrize("base", ["kf", "svsf", "gvbl-svsf"])
def test_imm_rows_and_reused_mode_measurements_change_no_bit(base):
    """predict -> predicted measurements -> update of an IMM on its IMMRows (rows and the kept mode measurements
    read) equals the same on plain lists (everything stacked and computed again), field by field, exactly."""
    rng = np.random.default_rng(11)
    modes = ({"kind": base, "motion": "cv"}, {"kind": {"kf": "ekf", "svsf": "gvbl-svsf"}.get(base, base), "motion": "ct"})
    imm = make_filter("imm", modes=modes, sigma_v=1.0, sigma_w=0.3)
    pred = imm.predict_many(_states(imm, rng), 0.1)
    assert type(pred) is IMMRows
    for ms, i in zip(pred.mode_lists, range(2)):
        assert [id(m) for m in ms] == [id(s.modes[i]) for s in pred]
        _assert_rows(ms)
    np.testing.assert_array_equal(pred.mu, np.array([s.mu for s in pred]))
    z_c, S_c = imm.predicted_measurements(pred)
    nu = rng.normal(0, 0.5, (T, M, 2))
    W, w0 = _weights(rng)
    a = imm.update_many(pred, nu, W, w0)
    b = imm.update_many(list(pred), nu, W, w0)
    np.testing.assert_array_equal(z_c, imm.predicted_measurements(list(pred))[0])
    np.testing.assert_array_equal(S_c, imm.predicted_measurements(list(pred))[1])
    for sa, sb in zip(a, b):
        for name in ("x", "P", "e_post", "mu"):
            np.testing.assert_array_equal(getattr(sa, name), getattr(sb, name))
        for ma, mb in zip(sa.modes, sb.modes):
            for name in ("x", "P", "e_post"):
                np.testing.assert_array_equal(getattr(ma, name), getattr(mb, name))


@pytest.mark.parametrize("kind", ["kf", "svsf", "gc-svsf", "gvbl-svsf"])
@pytest.mark.parametrize("memory", ["keep", "reset"])
def test_updates_carry_the_rows_of_the_states_they_return(kind, memory):
    """Every batched update given a StateRows returns one whose carried x, P, e_post are its states' fields bit for
    bit, the missed tracks' rows included (their memories zeroed with memory_after_miss = "reset"), and whose states
    equal those of the update on a plain list."""
    rng = np.random.default_rng(17)
    extra = {} if kind == "kf" else {"memory_after_miss": memory}
    flt = make_filter(kind, sigma_v=1.0, sigma_w=0.3, **extra)
    pred = flt.predict_many(_states(flt, rng), 0.1)
    pred = StateRows(pred, rows_of(pred, "x"), rows_of(pred, "P"), np.array([s.e_post for s in pred]) + 0.25)
    pred = StateRows([s.__class__(**{**s.__dict__, "e_post": e}) for s, e in zip(pred, pred.e_post)],
                     pred.x, pred.P, pred.e_post)  # non-zero memories, so that a reset shows in the rows
    nu = rng.normal(0, 0.5, (T, M, 2))
    W, w0 = _weights(rng)
    carried = flt.update_many(pred, nu, W, w0)
    _assert_rows(carried)
    assert (carried.e_post[:3] == (0.0 if memory == "reset" and kind != "kf" else pred.e_post[:3])).all()
    plain = flt.update_many(list(pred), nu, W, w0)
    for a, b in zip(carried, plain):
        for name in ("x", "P", "e_post"):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name))


def test_svsf_predict_rows_is_predict_of_the_states_with_those_rows():
    """SVSF.predict_rows (the IMM's mixed initial conditions as rows) equals predict_many of the states with x, P,
    e_post replaced by their rows (the IMM's former path), bit for bit, and carries the predicted rows."""
    from roadtrack.trackers.state import derive

    rng = np.random.default_rng(19)
    flt = make_filter("svsf", sigma_v=1.0, sigma_w=0.3)
    states = flt.predict_many(_states(flt, rng), 0.1)
    X = rows_of(states, "x") + rng.normal(0, 0.5, (T, 4))
    P = rows_of(states, "P") * rng.uniform(0.5, 2.0, (T, 1, 1))
    E = rng.normal(0, 0.3, (T, 2))
    got = flt.predict_rows(list(states), X, P, E, 0.1)
    _assert_rows(got)
    wants = flt.predict_many([derive(s, x=x.copy(), P=p.copy(), e_post=e.copy()) for s, x, p, e in zip(states, X, P, E)],
                             0.1)
    for g, want in zip(got, wants):
        for name in ("x", "P", "e_post", "F", "z_prev", "e_vel"):
            np.testing.assert_array_equal(getattr(g, name), getattr(want, name))
        assert g.tau == want.tau and type(g) is type(want)


def test_frozen_state_is_the_derived_state():
    """state.frozen_state builds the FilterState that derive_frozen makes from a template, field by field (the same
    objects), of type FilterState, and its dataclass fields are exactly those set."""
    import dataclasses

    from roadtrack.trackers.state import FilterState, derive_frozen, frozen_state

    x, P, e, F = np.arange(4.0), np.eye(4), np.ones(2), 2.0 * np.eye(4)
    info = {"k": np.ones(2)}
    template = FilterState(x=np.zeros(4), P=np.eye(4), info={"old": 1.0})
    got = frozen_state(x, P, e, F, info)
    want = derive_frozen(template, x=x, P=P, e_post=e, F=F, info=info)
    assert type(got) is FilterState
    assert list(got.__dict__) == [f.name for f in dataclasses.fields(FilterState)] == list(want.__dict__)
    assert all(getattr(got, k) is getattr(want, k) for k in want.__dict__)


def test_svsf_and_gvbl_states_built_field_by_field_are_the_derived_states():
    """svsf.svsf_state and gvbl.gvbl_state give the states derive_frozen makes from a template, field by field."""
    import dataclasses

    from roadtrack.trackers.filters.gvbl import GVBLState, gvbl_state
    from roadtrack.trackers.filters.svsf import SVSFState, svsf_state
    from roadtrack.trackers.state import derive_frozen

    x, P, e, F, v = np.arange(4.0), np.eye(4), np.ones(2), 2.0 * np.eye(4), np.full(2, 3.0)
    for cls, got, extra in ((SVSFState, svsf_state(x, P, e, F, {"a": 1.0}, v, 0.3, 2 * v),
                             {"z_prev": v, "tau": 0.3, "e_vel": None}),
                            (GVBLState, gvbl_state(x, P, e, F, {"a": 1.0}, v), {"psi_layer": v})):
        template = cls(x=np.zeros(4), P=np.eye(4))
        fields = {"x": x, "P": P, "e_post": e, "F": F, "info": got.info, **extra}
        if cls is SVSFState:
            fields["e_vel"] = got.e_vel
        want = derive_frozen(template, **fields)
        assert type(got) is cls
        assert list(got.__dict__) == [f.name for f in dataclasses.fields(cls)]
        assert all(getattr(got, k) is getattr(want, k) for k in want.__dict__)
