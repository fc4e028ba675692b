"""Code a user names on the command line (``--policy``, ``--tracker``): ``module:attr`` (an installed or already
importable module) or ``path/to/file.py:attr`` (that file, loaded as a module). A scenario or campaign file never
names code; this is never called on their contents, and the current directory is never put on ``sys.path``."""
from __future__ import annotations

import importlib
import importlib.util
import os
from typing import Any

from ..config import ConfigError, one_line


def is_code_spec(text: str) -> bool:
    """Whether ``text`` reads as ``module:attr`` or ``file.py:attr`` (a tracker *name* has no colon)."""
    target, sep, attr = text.rpartition(":")
    return bool(sep and target and attr)


def load_object(spec: str, option: str, noun: str = "name") -> Any:
    """The object named by ``spec`` (``module:attr``, ``module:Outer.inner`` or ``path/to/file.py:attr``).
    ConfigError at ``option`` (one line) when it cannot be loaded; ``noun`` names the attribute in it (e.g.
    ``module:function``)."""
    target, sep, attr = spec.rpartition(":")
    if not sep or not target or not attr:
        raise ConfigError(option, f"{spec!r}: expected module:{noun} or path/to/file.py:{noun}")
    try:
        obj: Any = _module(target, option)
    except ConfigError:
        raise
    except Exception as err:  # noqa: BLE001 - any import failure is the option's error
        raise ConfigError(option, f"cannot import {target!r} ({type(err).__name__}: {one_line(err)})") from None
    for part in attr.split("."):
        if not hasattr(obj, part):
            raise ConfigError(option, f"{target!r} has no attribute {attr!r}")
        obj = getattr(obj, part)
    return obj


def _module(target: str, option: str) -> Any:
    """A ``.py`` file path loaded as a module, else an importable module name."""
    if not target.endswith(".py"):
        return importlib.import_module(target)
    if not os.path.isfile(target):
        raise ConfigError(option, f"{target}: no such file")
    name = "roadtrack_user_" + os.path.splitext(os.path.basename(target))[0].replace("-", "_")
    spec = importlib.util.spec_from_file_location(name, target)
    if spec is None or spec.loader is None:
        raise ConfigError(option, f"{target}: cannot be loaded as a Python module")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module
