"""Filter state as an immutable value.

A filter never mutates a state; it returns a new one (`s1 = flt.predict(s0, dt)`). Filters that
need more than (x, P, e_post) subclass `FilterState` with extra fields that have defaults, e.g.
an IMM state carrying mode probabilities, or an SVSF state carrying the last step length.
Update a state with `dataclasses.replace(s, x=..., P=...)`, which keeps any subclass extras.
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


def freeze(*arrays: np.ndarray) -> None:
    """Make batched arrays read-only at once, so that `derive` given their rows (read-only views) has nothing to
    freeze per row."""
    for a in arrays:
        a.setflags(write=False)
