"""Filter state as an immutable value.

A filter never mutates a state; it returns a new one (`s1 = flt.predict(s0, dt)`). Filters that
need more than (x, P, e_post) subclass `FilterState` with extra fields that have defaults, e.g.
an IMM state carrying mode probabilities, or an SVSF state carrying the last step length.
Update a state with `dataclasses.replace(s, x=..., P=...)`, which keeps any subclass extras.

The batched filters build T states per call from rows of arrays they have just computed: `derive_frozen` makes a
state without __init__, and a `StateRows` list hands the stacked rows on to the next batched call of the scan, which
reads them (`rows_of`, `take_rows`) instead of stacking the T states again.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping

import numpy as np


def _frozen(a, name: str, ndim: int) -> np.ndarray:
    arr = np.array(a, dtype=np.float64)  # copy: the state owns its arrays
    if arr.ndim != ndim:
        raise ValueError(f"FilterState.{name} must be {ndim}-D, got shape {arr.shape}")
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True, eq=False)
class FilterState:
    """x (n,) state [px, py, vx, vy, ...]; P (n, n) covariance; e_post (m,) previous a-posteriori
    measurement error e_{z,k|k} (thesis §2.3 step 7, §4.3 step 7), used by the SVSF family and
    carried unchanged-or-recomputed by the KF; F (n, n) the transition Jacobian of the last `predict`
    (None after an update or at birth), which the SVSF's partitioned gain reads (thesis (3.29)-(3.35));
    info: named per-track diagnostics of the last update (e.g. boundary-layer widths, (m,) arrays or
    scalars), reported to the tables and the viewer. Arrays are float64 copies and read-only."""

    x: np.ndarray
    P: np.ndarray
    e_post: np.ndarray = field(default_factory=lambda: np.zeros(2))
    F: np.ndarray | None = None
    info: Mapping[str, np.ndarray] = field(default_factory=dict)

    def __post_init__(self) -> None:
        x = _frozen(self.x, "x", 1)
        P = _frozen(self.P, "P", 2)
        if P.shape != (x.size, x.size):
            raise ValueError(f"FilterState.P must be ({x.size}, {x.size}) for x of size {x.size}, got {P.shape}")
        object.__setattr__(self, "x", x)
        object.__setattr__(self, "P", P)
        object.__setattr__(self, "e_post", _frozen(self.e_post, "e_post", 1))
        if self.F is not None:
            object.__setattr__(self, "F", _frozen(self.F, "F", 2))


def derive(s: FilterState, **arrays: np.ndarray) -> FilterState:
    """A copy of `s` with fields replaced by arrays the caller has just computed and will not touch again
    (made read-only here, not copied or re-validated): the fast path of the batched filters."""
    new = object.__new__(type(s))
    d = new.__dict__
    d.update(s.__dict__)
    for name, a in arrays.items():
        if isinstance(a, np.ndarray) and a.flags.writeable:  # a view of a frozen batch is read-only already
            a.setflags(write=False)
        d[name] = a
    return new


def derive_frozen(s: FilterState, **fields) -> FilterState:
    """`derive` for fields whose arrays are read-only already (rows of batches made read-only by `freeze`): the same
    state without a check per array (the batched filters' per-track hot path)."""
    new = object.__new__(type(s))
    d = new.__dict__
    d.update(s.__dict__)
    d.update(fields)
    return new


def frozen_state(x: np.ndarray, P: np.ndarray, e_post: np.ndarray, F: np.ndarray | None, info: Mapping) -> FilterState:
    """FilterState(x, P, e_post, F, info) of read-only arrays without __init__: its fields set one by one in their
    declared order on the new instance, which costs half of `derive_frozen`'s copy of a template (the batched
    filters make T states per scan)."""
    new = object.__new__(FilterState)
    d = new.__dict__
    d["x"], d["P"], d["e_post"], d["F"], d["info"] = x, P, e_post, F, info
    return new


class StateRows(list):
    """A list of T states that carries their fields stacked: x (T, n), P (T, n, n), e_post (T, m) (each None when not
    carried), row t holding the very values of item t's field (the batched filter that made the list guarantees it).
    A batched filter given such a list reads the rows (`rows_of`) instead of stacking the states again; a copy or a
    slice of it is a plain list."""

    def __init__(self, states, x: np.ndarray | None = None, P: np.ndarray | None = None,
                 e_post: np.ndarray | None = None):
        super().__init__(states)
        self.x, self.P, self.e_post = x, P, e_post


def rows_of(states: list, name: str, idx: np.ndarray | None = None) -> np.ndarray:
    """Field `name` ("x", "P" or "e_post") of the states (of states[idx], idx (A,) int, when given) stacked: the rows a
    StateRows carries, else np.array of the states' fields."""
    a = getattr(states, name, None) if type(states) is StateRows else None
    if a is None:
        return np.array([getattr(states[t], name) for t in idx] if idx is not None else [getattr(s, name) for s in states])
    return a[idx] if idx is not None else a


def take_rows(states: list, idx: np.ndarray) -> list:
    """states[idx] (idx (A,) int) as a list, a StateRows carrying the rows when `states` carries them."""
    out = [states[t] for t in idx]
    if type(states) is not StateRows:
        return out
    return StateRows(out, *(None if a is None else a[idx] for a in (states.x, states.P, states.e_post)))


def updated_rows(preds: list, out: list, active: np.ndarray, x: np.ndarray, P: np.ndarray, e_post: np.ndarray,
                 reset: bool = False) -> list:
    """`out`, the states a batched update made from `preds` (T), as a StateRows carrying their x, P and e_post when
    `preds` carries all three: preds' rows with the rows `active` (A,) replaced by x (A, n), P (A, n, n) and e_post
    (A, m), the fields of the active tracks' new states in `out`, and with `reset` every other row's e_post set to 0
    (a filter whose miss handling resets the memory). Else `out` as it is. The new arrays are made read-only."""
    if type(preds) is not StateRows or preds.x is None or preds.P is None or preds.e_post is None:
        return out
    rows = [np.array(a) for a in (preds.x, preds.P, preds.e_post)]
    if reset:
        rows[2][:] = 0.0
    for a, new in zip(rows, (x, P, e_post)):
        a[active] = new
    freeze(*rows)
    return StateRows(out, *rows)


def freeze(*arrays: np.ndarray) -> None:
    """Make batched arrays read-only at once, so that `derive` given their rows (read-only views) has nothing to
    freeze per row."""
    for a in arrays:
        a.setflags(write=False)
