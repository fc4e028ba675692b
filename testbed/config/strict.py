"""Strict loading of frozen dataclasses from TOML-like dicts.

Every unknown key, wrong type or impossible value raises :class:`ConfigError`, whose one-line message
names the dotted key and what is allowed. Dataclass fields may carry ``metadata``:

* ``choices``: tuple of allowed values (strings);
* ``check``: ``(predicate, text)``, e.g. ``(lambda v: v > 0, "> 0")``;
* ``validate``: ``func(value, dotted_key)`` raising ConfigError, e.g. a resource limit (``testbed.config.limits.at_most``);
* ``limit``: the name of the resource limit the key is checked against (shown by ``testbed keys``);
* ``doc``: a short description (listed by ``testbed scenarios --keys``).

A dataclass's own ``__post_init__`` may raise ``ValueError``; it is reported at that table's path.
"""
from __future__ import annotations

import dataclasses
import math
import re
import tomllib
import types
import typing
from pathlib import Path
from typing import Any


class ConfigError(ValueError):
    """A malformed configuration: ``str(err)`` is one line naming the dotted key."""

    def __init__(self, path: str, message: str):
        self.path = path
        super().__init__(f"{path}: {message}" if path else message)


def _join(path: str, key: str | int) -> str:
    if isinstance(key, int):
        return f"{path}[{key}]"
    return f"{path}.{key}" if path else key


def type_name(tp: Any) -> str:
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        return " or ".join(type_name(a) for a in typing.get_args(tp))
    if origin is tuple:
        return f"list of {type_name(typing.get_args(tp)[0])}"
    if dataclasses.is_dataclass(tp):
        return "table"
    if tp is type(None):
        return "nothing"
    return getattr(tp, "__name__", str(tp))


def _convert(tp: Any, value: Any, path: str) -> Any:
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        options = [a for a in typing.get_args(tp) if a is not type(None)]
        if value is None and len(options) < len(typing.get_args(tp)):
            return None
        if len(options) == 1:  # Optional[X]: report X's own, precise error
            return _convert(options[0], value, path)
        for arg in options:
            try:
                return _convert(arg, value, path)
            except ConfigError:
                continue
        raise ConfigError(path, f"expected {type_name(tp)}, got {value!r}")
    if dataclasses.is_dataclass(tp):
        if not isinstance(value, dict):
            raise ConfigError(path, f"expected a table, got {value!r}")
        return from_dict(tp, value, path)
    if origin is tuple:
        args = typing.get_args(tp)
        if not isinstance(value, (list, tuple)):
            raise ConfigError(path, f"expected a list, got {value!r}")
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_convert(args[0], v, _join(path, i)) for i, v in enumerate(value))
        if len(args) != len(value):
            raise ConfigError(path, f"expected a list of {len(args)} values, got {len(value)}")
        return tuple(_convert(a, v, _join(path, i)) for i, (a, v) in enumerate(zip(args, value)))
    if origin is dict:
        if not isinstance(value, dict):
            raise ConfigError(path, f"expected a table, got {value!r}")
        return dict(value)
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(path, f"expected a number, got {value!r}")
        try:
            number = float(value)
        except OverflowError:  # an integer beyond float64
            raise ConfigError(path, f"expected a finite number, got an integer of {len(str(value))} digits") from None
        if not math.isfinite(number):
            raise ConfigError(path, f"expected a finite number, got {value!r}")
        return number
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(path, f"expected an integer, got {value!r}")
        return value
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(path, f"expected true or false, got {value!r}")
        return value
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(path, f"expected a string, got {value!r}")
        return value
    if tp is Any:
        return value
    raise ConfigError(path, f"unsupported field type {tp!r}")


def from_dict(cls: type, data: dict, path: str = "") -> Any:
    """Build dataclass ``cls`` from ``data``, strictly (see module docstring)."""
    if not isinstance(data, dict):
        raise ConfigError(path, f"expected a table, got {data!r}")
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    unknown = sorted(set(data) - set(fields))
    if unknown:
        raise ConfigError(_join(path, unknown[0]), f"unknown key; allowed: {', '.join(sorted(fields))}")
    kwargs = {}
    for name, field in fields.items():
        key_path = _join(path, name)
        if name not in data:
            if field.default is dataclasses.MISSING and field.default_factory is dataclasses.MISSING:
                raise ConfigError(key_path, f"missing required key ({type_name(hints[name])})")
            continue
        value = _convert(hints[name], data[name], key_path)
        choices = field.metadata.get("choices")
        if choices is not None and value not in choices:
            raise ConfigError(key_path, f"{value!r} is not allowed; allowed: {', '.join(map(str, choices))}")
        check = field.metadata.get("check")
        if check is not None and value is not None:
            predicate, text = check
            if not predicate(value):
                raise ConfigError(key_path, f"{value!r} is not allowed; must be {text}")
        validate = field.metadata.get("validate")
        if validate is not None and value is not None:
            validate(value, key_path)
        kwargs[name] = value
    try:
        return cls(**kwargs)
    except ConfigError as err:  # raised by __post_init__ with a key relative to this table
        raise ConfigError(_join(path, err.path), str(err).split(": ", 1)[-1]) from None
    except (ValueError, TypeError, ArithmeticError) as err:
        msg = str(err).splitlines()[0] if str(err) else type(err).__name__
        named = re.match(r"^\w+\.(\w+): (.*)$", msg)  # "LidarConfig.max_range_m: ..." from a __post_init__
        if named and named.group(1) in fields:
            raise ConfigError(_join(path, named.group(1)), named.group(2)) from None
        raise ConfigError(path or cls.__name__, msg) from None


def to_dict(obj: Any) -> Any:
    """Plain-data (TOML/JSON-able) form of a config dataclass."""
    if dataclasses.is_dataclass(obj):
        return {f.name: to_dict(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if isinstance(obj, (list, tuple)):
        return [to_dict(v) for v in obj]
    if isinstance(obj, dict):
        return {k: to_dict(v) for k, v in obj.items()}
    return obj


def positive(text: str = "> 0") -> dict:
    return {"check": (lambda v: v > 0, text)}


def non_negative() -> dict:
    return {"check": (lambda v: v >= 0, ">= 0")}


def field(default: Any = dataclasses.MISSING, *, doc: str = "", **meta: Any) -> Any:
    """``dataclasses.field`` with validation metadata (``choices=``, ``check=``) and a doc string."""
    metadata = dict(meta)
    metadata["doc"] = doc
    if isinstance(default, (list, dict)) or dataclasses.is_dataclass(default):
        value = default
        return dataclasses.field(default_factory=lambda: value, metadata=metadata)
    return dataclasses.field(default=default, metadata=metadata)


def show_path(path: str | Path, width: int = 120) -> str:
    """``path`` for a one-line message: quoted when it holds control characters, shortened beyond ``width``."""
    text = str(path)
    if len(text) > width:
        text = text[: width // 2] + "..." + text[-width // 2:]
    if any(ord(c) < 32 or ord(c) == 127 for c in text):
        return repr(text)
    return text


def one_line(err: BaseException | str) -> str:
    """The first non-empty line of ``str(err)``, stripped ('' when there is none)."""
    for line in str(err).splitlines():
        if line.strip():
            return line.strip()
    return ""


def parse_sets(items: list[str]) -> dict:
    """``KEY=VALUE`` pairs, VALUE read as a TOML value (a bare word is a string)."""
    out = {}
    for item in items:
        key, sep, raw = item.partition("=")
        if not sep or not key.strip():
            raise ConfigError("--set", f"{item!r}: expected KEY=VALUE, e.g. sensor.clutter.density_per_m2=0.01")
        try:
            value = tomllib.loads(f"v = {raw}")["v"]
        except tomllib.TOMLDecodeError:
            value = raw
        out[key.strip()] = value
    return out
