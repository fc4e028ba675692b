"""Typed, validated parameters of the tracker roles (filters, associators, managers).

Each role's parameters are a frozen dataclass whose fields are made with `param(default, doc, ...)`.
`load(cls, data, path)` builds one from a plain dict strictly: an unknown key, a wrong type or a value
outside `choices` / `check` raises `ParamError` naming the dotted key (e.g. "filter.sigma_v: expected a
number, got '2'"), in the same one-line format as the testbed's scenario errors.

Every number is also bounded, so that no accepted value overflows or exhausts memory: a float (also inside a
list) is 0 or of magnitude in [FLOAT_MIN, FLOAT_MAX], an integer in [-INT_MAX, INT_MAX], unless its field
names tighter `bounds`. Squared, cubed or inverted, such values stay far inside float64 (a covariance of
FLOAT_MAX^2 * 10^4 steps is 1e16); the bounds are checked against every filter, associator and manager in
tests/test_tracker_param_bounds.py, and explained in docs/limits.md.
"""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from typing import Any, Callable


class ParamError(ValueError):
    """A bad tracker parameter: `path` is the dotted key, `str(err)` is "path: what is wrong"."""

    def __init__(self, path: str, message: str):
        self.path = path
        super().__init__(f"{path}: {message}" if path else message)


FLOAT_MAX = 1e6
"""Largest magnitude of a float parameter: 1000 km, 1000 km/s, 10^6 nats or per m^2 (defaults are <= 40)."""
FLOAT_MIN = 1e-9
"""Smallest non-zero magnitude of a float parameter (a 1 nm noise std; densities of 1e-9 per m^2)."""
INT_MAX = 1_000_000
"""Largest magnitude of an integer parameter (10^6 scans is 28 h at 10 Hz)."""


def param(default: Any, doc: str, *, choices: tuple | None = None,
          check: tuple[Callable[[Any], bool], str] | None = None,
          bounds: tuple[float, float] | None = None) -> Any:
    """A dataclass field with a default, a one-line doc, optional allowed `choices`, a `check`
    (predicate, text) such as (lambda v: v > 0, "> 0") and `bounds` (least, largest) that replace the
    default magnitude bounds of the module docstring (for parameters that size memory or work)."""
    meta: dict[str, Any] = {"doc": doc}
    if choices is not None:
        meta["choices"] = choices
    if check is not None:
        meta["check"] = check
    if bounds is not None:
        meta["bounds"] = bounds
    if isinstance(default, (list, dict)):
        return dataclasses.field(default_factory=lambda: default, metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


POSITIVE = (lambda v: v > 0, "> 0")
NON_NEGATIVE = (lambda v: v >= 0, ">= 0")
PROBABILITY = (lambda v: 0 < v <= 1, "in (0, 1]")
OPEN_PROBABILITY = (lambda v: 0 < v < 1, "in (0, 1)")


def _convert(tp: Any, value: Any, path: str) -> Any:
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        args = typing.get_args(tp)
        if value is None and type(None) in args:
            return None
        for a in args:
            if a is type(None):
                continue
            try:
                return _convert(a, value, path)
            except ParamError:
                continue
        raise ParamError(path, f"expected {' or '.join(getattr(a, '__name__', str(a)) for a in args)}, got {value!r}")
    if origin is tuple:
        if not isinstance(value, (list, tuple)):
            raise ParamError(path, f"expected a list, got {value!r}")
        inner = typing.get_args(tp)[0]
        return tuple(_convert(inner, v, f"{path}[{i}]") for i, v in enumerate(value))
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise ParamError(path, f"expected a finite number, got {value!r}")
        return float(value)
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ParamError(path, f"expected an integer, got {value!r}")
        return value
    if tp is bool:
        if not isinstance(value, bool):
            raise ParamError(path, f"expected true or false, got {value!r}")
        return value
    if tp is str:
        if not isinstance(value, str):
            raise ParamError(path, f"expected a string, got {value!r}")
        return value
    if tp is dict or origin is dict:
        if not isinstance(value, dict):
            raise ParamError(path, f"expected a table, got {value!r}")
        return dict(value)
    if tp is Any:
        return value
    raise ParamError(path, f"unsupported parameter type {tp!r}")


def load(cls: type, data: dict, path: str) -> Any:
    """Build parameter dataclass `cls` from `data` strictly (see module docstring)."""
    if not isinstance(data, dict):
        raise ParamError(path, f"expected a table, got {data!r}")
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    unknown = sorted(set(data) - set(fields))
    if unknown:
        raise ParamError(f"{path}.{unknown[0]}", f"unknown key; allowed: {', '.join(sorted(fields))}")
    kwargs = {}
    for name, value in data.items():
        key = f"{path}.{name}"
        v = _convert(hints[name], value, key)
        meta = fields[name].metadata
        if "choices" in meta and v not in meta["choices"]:
            raise ParamError(key, f"{v!r} is not allowed; allowed: {', '.join(map(str, meta['choices']))}")
        if "check" in meta and v is not None and not meta["check"][0](v):
            raise ParamError(key, f"{v!r} is not allowed; must be {meta['check'][1]}")
        check_bounds(v, meta.get("bounds"), key)
        kwargs[name] = v
    try:
        return cls(**kwargs)
    except ParamError as err:
        raise ParamError(f"{path}.{err.path}", str(err).split(": ", 1)[-1]) from None
    except ValueError as err:
        raise ParamError(path, str(err).splitlines()[0]) from None


def check_bounds(value: Any, bounds: tuple[float, float] | None, key: str) -> None:
    """ParamError at `key` when a number in `value` (a number or a nested list) is outside `bounds`, or, without
    them, outside the default magnitude bounds (module docstring)."""
    if isinstance(value, (list, tuple)):
        for i, v in enumerate(value):
            check_bounds(v, bounds, f"{key}[{i}]")
        return
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return
    if bounds is not None:
        if not bounds[0] <= value <= bounds[1]:
            raise ParamError(key, f"{value!r} is not allowed; must be in [{bounds[0]:g}, {bounds[1]:g}]")
    elif isinstance(value, int):
        if abs(value) > INT_MAX:
            raise ParamError(key, f"{value!r} is not allowed; integers must be within +-{INT_MAX:g}")
    elif value != 0 and not FLOAT_MIN <= abs(value) <= FLOAT_MAX:
        raise ParamError(key, f"{value!r} is not allowed; numbers must be 0 or of magnitude {FLOAT_MIN:g} to "
                              f"{FLOAT_MAX:g}")


def defaults(cls: type) -> Any:
    """The parameter object with every default."""
    return load(cls, {}, cls.__name__)


def _type_name(tp: Any) -> str:
    if typing.get_origin(tp) in (typing.Union, types.UnionType):
        return " or ".join("nothing" if a is type(None) else _type_name(a) for a in typing.get_args(tp))
    if typing.get_origin(tp) is tuple:
        return f"list of {_type_name(typing.get_args(tp)[0])}"
    return getattr(tp, "__name__", str(tp))


def describe(cls: type) -> list[tuple[str, str, str, str]]:
    """(name, type, default, doc) of every parameter of `cls`, for `testbed keys`."""
    hints = typing.get_type_hints(cls)
    rows = []
    for f in dataclasses.fields(cls):
        if not f.init:
            continue
        default = f.default if f.default is not dataclasses.MISSING else (
            f.default_factory() if f.default_factory is not dataclasses.MISSING else "required")
        doc = f.metadata.get("doc", "")
        if "choices" in f.metadata:
            doc += f" (one of: {', '.join(map(str, f.metadata['choices']))})"
        if "check" in f.metadata:
            doc += f" (must be {f.metadata['check'][1]})"
        rows.append((f.name, _type_name(hints[f.name]), repr(default), doc))
    return rows
