"""Strict JSON for every file the tool writes (``scores.json``, ``summary.json``, a campaign's ``meta.json``
and ``scenarios.json``): a number that is not finite (NaN, +-infinity) is written as ``null``, since JSON has
no such numbers and strict parsers refuse Python's bare ``NaN``; numpy scalars and arrays are written as plain
numbers and lists.

    text = json_text({"pos_rmse_m": float("nan"), "n": np.int64(3)}, indent=2)  # '{"pos_rmse_m": null, ...}'
"""
from __future__ import annotations

import json
import math
from typing import Any, Callable

import numpy as np


def finite(obj: Any, default: Callable[[Any], Any] | None = None) -> Any:
    """``obj`` with every non-finite float (Python's or numpy's) replaced by None, inside dicts, lists and
    tuples; numpy scalars and arrays as Python numbers and lists; any other object through ``default`` (once)
    when given, else as it is."""
    if isinstance(obj, float):  # also numpy.float64
        return float(obj) if math.isfinite(obj) else None
    if obj is None or isinstance(obj, (str, int)):  # bool is an int
        return obj
    if isinstance(obj, dict):
        return {_key(k): finite(v, default) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [finite(v, default) for v in obj]
    if isinstance(obj, (np.generic, np.ndarray)):
        return finite(obj.tolist(), default)
    if default is not None:
        return finite(default(obj))
    return obj


def _key(key: Any) -> Any:
    """A dict key JSON can hold: numpy scalars as Python ones, a non-finite float as its text (``"nan"``)."""
    if isinstance(key, np.generic):
        key = key.item()
    if isinstance(key, float) and not math.isfinite(key):
        return str(key)
    return key


def json_text(obj: Any, **kw: Any) -> str:
    """``json.dumps(obj, **kw)`` of :func:`finite` ``(obj, kw.pop("default"))`` with ``allow_nan=False``: text
    every JSON parser reads (NaN and infinities are ``null``)."""
    return json.dumps(finite(obj, kw.pop("default", None)), allow_nan=False, **kw)
