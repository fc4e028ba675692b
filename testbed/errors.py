"""One-line errors for every command: exit codes, ``--debug`` and the last-resort handler.

Exit codes (all commands): 0 success; 1 run-time failure (a tracker diverged, the disk is full, a worker
died: what was finished is kept); 2 bad input (malformed file, bad option, unusable output folder), nothing
run; 130 interrupted (Ctrl-C), what was finished is kept.

``guarded(func, args, debug)`` runs a command and turns any exception into that code and ONE line on
stderr: ``error: WHAT`` (no traceback unless ``debug``; with it, the traceback is printed too).
"""
from __future__ import annotations

import errno
import os
import sys
import traceback
from typing import Any, Callable

from .config import ConfigError, one_line  # noqa: F401 - one_line is part of this module's API


class RunError(RuntimeError):
    """A run-time failure with a message already fit for the user (exit 1)."""


def describe_os_error(err: OSError) -> str:
    """``path: what happened`` for an OSError, e.g. ``runs/x/tracks.parquet: no space left on device``."""
    what = os.strerror(err.errno).lower() if err.errno else one_line(err) or type(err).__name__
    if err.errno == errno.ENOSPC:
        what = "no space left on device (free some space and run again)"
    where = err.filename if err.filename is not None else ""
    return f"{where}: {what}" if where else what


def exit_code(err: BaseException) -> int:
    if isinstance(err, KeyboardInterrupt):
        return 130
    if isinstance(err, ConfigError):
        return 2
    return 1


def message(err: BaseException) -> str:
    """The one line printed after ``error: ``."""
    if isinstance(err, ConfigError | RunError):
        return one_line(err)
    if isinstance(err, OSError):
        return describe_os_error(err)
    text = one_line(err)
    return f"internal error, {type(err).__name__}{': ' + text if text else ''} (run again with --debug for " \
           f"the traceback, and please report it)"


def report(err: BaseException, debug: bool = False) -> int:
    """Print ``err`` as one line on stderr (and the traceback if ``debug``); return its exit code."""
    if debug:
        traceback.print_exception(err, file=sys.stderr)
    if isinstance(err, KeyboardInterrupt):
        print("interrupted", file=sys.stderr)
    else:
        print(f"error: {message(err)}", file=sys.stderr)
    return exit_code(err)


def guarded(func: Callable[[Any], int], args: Any, debug: bool = False) -> int:
    """``func(args)``, with every exception (incl. Ctrl-C) reported by :func:`report`."""
    try:
        return func(args)
    except (Exception, KeyboardInterrupt) as err:  # noqa: BLE001 - the last resort: one line, never a traceback
        return report(err, debug)
