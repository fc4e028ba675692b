"""Boundary checks: cast once, and fail with a one-line ValueError naming the argument."""

from __future__ import annotations

import numpy as np


def float_array(name: str, x, shape: tuple) -> np.ndarray:
    """`x` as a finite float64 array of `shape` (None = any length on that axis)."""
    try:
        a = np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected a float array of shape {_fmt(shape)}") from None
    if a.ndim != len(shape):
        raise ValueError(f"{name}: expected shape {_fmt(shape)}, got {a.shape}")
    for s, n in zip(shape, a.shape):  # a plain loop: called ~30 times a frame, mostly on a few rows
        if s is not None and s != n:
            raise ValueError(f"{name}: expected shape {_fmt(shape)}, got {a.shape}")
    if not np.isfinite(a).all():
        raise ValueError(f"{name}: contains NaN or inf")
    return a


def int_array(name: str, x, shape: tuple) -> np.ndarray:
    """`x` as an int64 array of `shape`; floats are accepted only if they hold whole numbers."""
    a = np.asarray(x)
    if a.size == 0:
        a = a.astype(np.int64)
    if a.ndim != len(shape) or any(s is not None and s != n for s, n in zip(shape, a.shape)):
        raise ValueError(f"{name}: expected shape {_fmt(shape)}, got {a.shape}")
    if a.dtype.kind in "iu":
        return a.astype(np.int64, copy=False)
    if a.dtype.kind != "f" or not np.all(np.isfinite(a)) or np.any(a != np.round(a)):
        raise ValueError(f"{name}: expected integers, got dtype {a.dtype}")
    return a.astype(np.int64)


def finite(name: str, value) -> None:
    """Raise unless `value` is a finite real number."""
    real = isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)
    if not (real and np.isfinite(value)):
        raise ValueError(f"{name}: expected a finite number, got {value!r}")


def positive(name: str, value, allow_zero: bool = False) -> None:
    """Raise unless `value` is a finite real number > 0 (>= 0 with allow_zero)."""
    real = isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)
    if not (real and np.isfinite(value) and (value >= 0 if allow_zero else value > 0)):
        raise ValueError(f"{name}: expected a finite number {'>=' if allow_zero else '>'} 0, got {value!r}")


def positive_int(name: str, value, allow_zero: bool = False) -> None:
    """Raise unless `value` is an int > 0 (>= 0 with allow_zero)."""
    integer = isinstance(value, (int, np.integer)) and not isinstance(value, bool)
    if not (integer and (value >= 0 if allow_zero else value > 0)):
        raise ValueError(f"{name}: expected an int {'>=' if allow_zero else '>'} 0, got {value!r}")


def choice(name: str, value: str, registry: dict) -> None:
    """Raise unless `value` is a key of `registry`, listing the valid names."""
    if value not in registry:
        raise ValueError(f"{name}: unknown method {value!r}; valid: {', '.join(sorted(registry))}")


def _fmt(shape: tuple) -> str:
    return "(" + ", ".join("N" if s is None else str(s) for s in shape) + ("," if len(shape) == 1 else "") + ")"
