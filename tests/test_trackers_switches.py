"""Every switch means the same on the batched path the tracker runs as on the per-track reference (issue 33).

The switches are read from the filters' parameter tables (trackers.filters.FILTERS): every field with `choices`
and every bool field, in their full cross product, so a new switch is covered without editing this file. Each
buildable setting, and an IMM of two modes of that setting, runs a hand-made scenario of 5 tracks over 6 scans
(hard and PDA weights, gated measurements left without weight, w0 = 1 rows, a scan without measurements (M = 0),
first updates after missed scans, a manoeuvre; with detection_R, every detection with its own covariance) twice: once through the batched forms the tracker calls
(filters.base.batch_*), once through the per-track predict / predicted_measurement / update. Both chains are fed
the same innovations each scan; every field of every state (x, P, e_post, F, the SVSF's z_prev / tau / e_vel, the
GVBL's layer, the IMM's mode states and mu, the diagnostics) must agree to 1e-10, and a track the per-track
update returns unchanged (the same object) is returned unchanged by the batched one too.
A setting the registry refuses to build must be refused with a one-line ValueError."""

from __future__ import annotations

import dataclasses
import itertools
import typing
from contextlib import ExitStack
from unittest import mock

import numpy as np
import pytest

from roadtrack.trackers.filters import FILTERS, make_filter
from roadtrack.trackers.filters.base import batch_predict, batch_predicted_measurements, batch_update, takes_detection_R
from roadtrack.trackers.filters.imm import IMMFilter
from roadtrack.trackers.registry import WRAPPERS
from state_fields import state_fields

SIGMAS = {"sigma_v": 2.0, "sigma_w": 0.5}
EXERCISE = {"gvbl-svsf": {"psi_max": 0.5}}
"""Non-switch values that make a kind's switches matter: the GVBL's switch rules and robust gains act only in its
robust regime, which psi_max = 0.5 m reaches on most scans of the scenario (psi_max = 20 m never does)."""


def switches(params: type) -> dict[str, tuple]:
    """name -> allowed values of every switch of a parameter dataclass: fields with `choices`, and bool fields."""
    hints = typing.get_type_hints(params)
    out = {}
    for f in dataclasses.fields(params):
        if f.init and "choices" in f.metadata:
            out[f.name] = tuple(f.metadata["choices"])
        elif f.init and hints[f.name] is bool:
            out[f.name] = (False, True)
    return out


def cross_product(params: type) -> list[dict]:
    names = switches(params)
    return [dict(zip(names, values)) for values in itertools.product(*names.values())]


def _try_build(kind: str, table: dict):
    try:
        return make_filter(kind, **table), None
    except ValueError as err:  # ParamError included
        return None, err


def _settings() -> tuple[list[tuple[str, dict]], list[tuple[str, dict, str]]]:
    """(built, refused): every single-model filter kind with every switch combination as (kind, table), and the
    combinations its build refuses as (kind, table, message); then an IMM over two modes of every built setting
    (the second with a larger sigma_v and, where the kind runs it, the CT model), crossed with the IMM's own
    switches (none today)."""
    built, refused, modes = [], [], []
    for kind, fk in FILTERS.items():
        if kind in WRAPPERS:
            continue
        for combo in cross_product(fk.params):
            table = {**SIGMAS, **EXERCISE.get(kind, {}), **combo}
            flt, err = _try_build(kind, table)
            if err is not None:
                refused.append((kind, combo, str(err)))
                continue
            built.append((kind, table))
            other = {**table, "sigma_v": 6.0}
            if table.get("motion", "cv") == "cv" and _try_build(kind, {**other, "motion": "ct"})[1] is None:
                other["motion"] = "ct"
            modes.append(({"kind": kind, **table}, {"kind": kind, **other}))
    for imm_combo in cross_product(FILTERS["imm"].params):
        built += [("imm", {**imm_combo, "modes": pair, "sigma_w": SIGMAS["sigma_w"]}) for pair in modes]
    return built, refused


BUILT, REFUSED = _settings()


def _id(setting: tuple[str, dict]) -> str:
    kind, table = setting
    if kind == "imm":
        table = {k: v for k, v in table["modes"][0].items() if k not in SIGMAS and k not in EXERCISE.get(kind, {})}
        return "imm[" + _id((table.pop("kind"), table)) + "]"
    return kind + "".join(f"-{k}={v}" for k, v in table.items() if k not in SIGMAS and k not in EXERCISE.get(kind, {}))


# ------------------------------------------------------------------------------------------------ the scenario
X0 = np.array([[0.0, 0.0, 5.0, 1.0], [30.0, 10.0, -3.0, 2.0], [60.0, -20.0, 4.0, -4.0], [90.0, 5.0, 0.0, 6.0],
               [120.0, 40.0, 8.0, 0.0]])
P0 = np.diag([1.0, 1.0, 9.0, 9.0])
DTS = (0.1, 0.1, 0.2, 0.1, 0.1, 0.1)
OFFSETS = np.array([[0.3, -0.2], [-0.6, 0.4], [1.2, 0.1], [-0.1, -0.9], [0.5, 0.5], [-1.4, 0.8]])
"""Measurement offsets from the truth [m], hand-picked: inside and outside the SVSF layers (3 sigma_w = 1.5 m)."""
ASSOC = (
    # scan 0: a hard association, PDA over a measurement and a clutter point, a PDA with w0 = 0.5, a gated
    # measurement with no weight (w0 = 1), no measurement in the gate
    {0: {0: 1.0}, 1: {"w0": 0.2, 1: 0.6, 5: 0.2}, 2: {"w0": 0.5, 2: 0.5}, 3: {"w0": 1.0}, 4: {}},
    {},  # scan 1: no measurements at all (M = 0)
    {0: {"w0": 0.1, 0: 0.9}, 1: {1: 1.0}, 2: {"w0": 0.3, 2: 0.4, 5: 0.3}, 3: {},
     4: {"w0": 1.0, 4: 1e-12}},  # a w0 = 1 row with a negligible weight left over
    {0: {}, 1: {"w0": 0.25, 1: 0.75}, 2: {}, 3: {3: 1.0}, 4: {"w0": 0.4, 4: 0.35, 5: 0.25}},  # first updates of 3, 4
    {0: {0: 1.0}, 1: {}, 2: {2: 1.0}, 3: {"w0": 0.15, 3: 0.85}, 4: {4: 1.0}},
    {0: {"w0": 0.05, 0: 0.95}, 1: {}, 2: {"w0": 0.2, 2: 0.8}, 3: {"w0": 0.3, 3: 0.4, 5: 0.3}, 4: {4: 1.0}},
)
"""Per scan, per track: its weights {measurement index: beta, "w0": beta0} (missing w0: 0; {} : no weight, w0 = 1).
Measurement j < 5 is track j's detection, 5 a clutter point beside the one track that uses it (track 0 if none)."""


def truth(t: int, time: float) -> np.ndarray:
    """Track t's true position [m] at `time` [s]: NCV, except track 2, which turns hard from 0.35 s."""
    p = X0[t, :2] + X0[t, 2:] * time
    if t == 2 and time > 0.35:
        p = p + 40.0 * np.array([1.0, 2.0]) * (time - 0.35) ** 2
    return p


def detection_R(M: int) -> np.ndarray:
    """(M, 2, 2) distinct per-detection covariances [m^2] (the detection_R switch): elongated, rotated, some wider
    and some narrower than sigma_w^2 = 0.25 m^2."""
    out = np.zeros((M, 2, 2))
    for j in range(M):
        c, s = np.cos(0.7 * j), np.sin(0.7 * j)
        U = np.array([[c, -s], [s, c]])
        out[j] = U @ np.diag([0.05 + 0.12 * j, 0.02 + 0.3 * (j % 3)]) @ U.T
    return out


def scan(k: int, z_hat: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """nu (T, M, 2) = z_j - z_hat_t, W (T, M), w0 (T,) of scan k for the predicted measurements z_hat (T, 2)."""
    rows, time = ASSOC[k], sum(DTS[:k + 1])
    if not rows:
        return np.zeros((len(X0), 0, 2)), np.zeros((len(X0), 0)), np.ones(len(X0))
    near = [t for t, row in rows.items() if 5 in row] or [0]  # a clutter point no track uses in scan 4
    Z = np.array([truth(j, time) + OFFSETS[(j + k) % len(OFFSETS)] for j in range(5)]
                 + [truth(near[0], time) + np.array([1.1, -0.7])])
    W, w0 = np.zeros((len(X0), len(Z))), np.ones(len(X0))
    for t, row in rows.items():
        for j, beta in row.items():
            if j != "w0":
                W[t, j] = beta
        w0[t] = row.get("w0", 0.0 if row else 1.0)
    return Z[None] - z_hat[:, None], W, w0


# ---------------------------------------------------------------------------------------------------- checks
def assert_same(a, b, where: str) -> None:
    """Same type, same fields, each equal to 1e-10 (relative, or absolute near 0; NaN equals NaN)."""
    fa, fb = state_fields(a), state_fields(b)
    assert type(a) is type(b) and set(fa) == set(fb), (where, type(a), type(b), set(fa) ^ set(fb))
    keys = [k for k in fa if fa[k] is not None or fb[k] is not None]
    assert all(fa[k] is not None and fb[k] is not None for k in keys), (where, keys)
    ua, ub = ([np.asarray(f[k], dtype=np.float64) for k in keys] for f in (fa, fb))
    assert [u.shape for u in ua] == [u.shape for u in ub], (where, keys)
    flat = [np.concatenate([u.ravel() for u in us] + [np.zeros(0)]) for us in (ua, ub)]
    if not np.allclose(*flat, rtol=1e-10, atol=1e-10, equal_nan=True):  # one check per state; details if it fails
        for k, u, v in zip(keys, ua, ub):
            np.testing.assert_allclose(u, v, rtol=1e-10, atol=1e-10, err_msg=f"{where}: {k}")


def batched_only(flt) -> ExitStack:
    """For an IMM, a context in which its per-track methods fail: its batched forms must not fall back to them."""
    stack = ExitStack()
    if isinstance(flt, IMMFilter):
        for name in ("predict", "predicted_measurement", "update", "_state"):
            stack.enter_context(mock.patch.object(IMMFilter, name, side_effect=AssertionError(f"per-track {name}")))
    return stack


def batched_run(flt) -> list[tuple]:
    """The scenario through the batched forms the tracker calls: per scan (predictions, z_hat (T, 2), S (T, 2, 2),
    the scan's (nu, W, w0), updated states)."""
    steps, states = [], [flt.initial_state(x, P0) for x in X0]
    own_R = takes_detection_R(flt)  # read before the per-track methods are replaced
    with batched_only(flt):
        for k, dt in enumerate(DTS):
            pred = batch_predict(flt, states, dt)
            z_hat, S = batch_predicted_measurements(flt, pred)
            nu, W, w0 = scan(k, z_hat)
            states = batch_update(flt, pred, nu, W, w0, detection_R(W.shape[1]) if own_R else None)
            steps.append((pred, z_hat, S, (nu, W, w0), states))
    return steps


def run_both(flt) -> None:
    """The scenario through the batched forms and through the per-track ones (fed the same innovations), compared
    after every step."""
    single = [flt.initial_state(x, P0) for x in X0]
    for k, (pb, z_hat, S, (nu, W, w0), batch) in enumerate(batched_run(flt)):
        ps = [flt.predict(s, DTS[k]) for s in single]
        for t, (u, v) in enumerate(zip(pb, ps)):
            assert_same(u, v, f"scan {k} predict, track {t}")
            z1, S1 = flt.predicted_measurement(v)
            np.testing.assert_allclose(z_hat[t], z1, rtol=1e-10, atol=1e-10, err_msg=f"scan {k} z_hat {t}")
            np.testing.assert_allclose(S[t], S1, rtol=1e-10, atol=1e-10, err_msg=f"scan {k} S {t}")
        R = detection_R(W.shape[1])
        single = [flt.update(s, nu[t, W[t] > 0], W[t, W[t] > 0], w0[t],
                             **({"R": R[W[t] > 0]} if takes_detection_R(flt) else {})) for t, s in enumerate(ps)]
        for t, (u, v) in enumerate(zip(batch, single)):
            assert_same(u, v, f"scan {k} update, track {t}")
            assert (u is pb[t]) == (v is ps[t]), f"scan {k} track {t}: the prediction itself on one path only"


@pytest.mark.parametrize("kind, table", BUILT, ids=[_id(s) for s in BUILT])
def test_batched_equals_per_track_for_every_switch(kind, table):
    run_both(make_filter(kind, **table))


def test_the_switch_tables_are_read_and_refusals_are_one_line_errors():
    """The cross product has every switch of every kind (a GVBL alone has 192 combinations, 144 buildable), each kind
    builds in some combination, and a refused combination is a ValueError of one line (e.g. the 'ct' model for the
    standard SVSF, a second-order EKF without measurement Hessians)."""
    kinds = {k for k in FILTERS if k not in WRAPPERS}
    assert {k for k, _ in BUILT} == kinds | {"imm"}
    assert set(switches(FILTERS["gvbl-svsf"].params)) >= {"motion", "switch", "robust_lower", "ey_memory",
                                                          "apda_layer", "memory_after_miss"}
    assert sum(k == "gvbl-svsf" for k, _ in BUILT) == 144 and len(cross_product(FILTERS["gvbl-svsf"].params)) == 192
    assert switches(FILTERS["kf"].params)["detection_R"] == (False, True)
    assert switches(FILTERS["ekf"].params)["second_order"] == (False, True)
    assert sum(k == "imm" for k, _ in BUILT) == sum(k != "imm" for k, _ in BUILT)
    for kind, combo, message in REFUSED:
        assert message and "\n" not in message, (kind, combo, message)


def test_the_scenario_reaches_the_branches_the_switches_select():
    """The scenario is not trivially equal on both paths: the GVBL (psi_max = 0.5 m) runs both regimes, the SVSF's
    innovations fall inside and outside its layer, tracks 3 and 4 make a first update (no z_prev: position rows
    only) at scan 3 and use the artificial velocity at scan 4, and the empty scan 1 meets non-zero memories."""
    gvbl = batched_run(make_filter("gvbl-svsf", **SIGMAS, **EXERCISE["gvbl-svsf"]))
    regimes = {s.info["regime"] for *_, states in gvbl for s in states if s.info}
    assert regimes == {0.0, 1.0}
    svsf = batched_run(make_filter("svsf", **SIGMAS))
    chatter = [bool(np.max(s.info["chatter"]) > 0) for *_, states in svsf for s in states if s.info]
    assert any(chatter) and not all(chatter)
    for t in (3, 4):
        assert "psi_v" not in svsf[3][4][t].info and "psi_v" in svsf[4][4][t].info
    assert svsf[1][3][0].shape == (5, 0, 2) and min(np.abs(s.e_post).max() for s in svsf[1][0][:3]) > 0.01
