"""One-line errors for every command: exit codes, ``--debug`` and the last-resort handler.

Exit codes (all commands): 0 success; 1 run-time failure (a tracker diverged, the disk is full, a worker
died: what was finished is kept); 2 bad input (malformed file, bad option, unusable output folder), nothing
run; 128 + the signal's number when stopped by a signal, what was finished is kept: 130 Ctrl-C (SIGINT),
143 SIGTERM (``kill``, ``timeout``, a batch scheduler), 129 SIGHUP (the terminal closed), the codes a shell
reports for a process killed by that signal.

``guarded(func, args, debug)`` runs a command and turns any exception into that code and ONE line on
stderr: ``error: WHAT`` (no traceback unless ``debug``; with it, the traceback is printed too). While it runs,
SIGTERM and SIGHUP raise :class:`Terminated` in the main thread, a KeyboardInterrupt: every path that keeps
the finished work on Ctrl-C keeps it on those signals too (:func:`stop_signals_interrupt`).
"""
from __future__ import annotations

import contextlib
import errno
import os
import signal
import sys
import threading
import traceback
from typing import Any, Callable, Iterator

from ..config import ConfigError, one_line  # noqa: F401 - one_line is part of this module's API


class RunError(RuntimeError):
    """A run-time failure with a message already fit for the user (exit 1)."""


STOP_SIGNALS = ("SIGTERM", "SIGHUP")
"""Signals that stop a command like Ctrl-C (see :func:`stop_signals_interrupt`)."""


class Terminated(KeyboardInterrupt):
    """SIGTERM or SIGHUP (``signum``) received: raised in the main thread like Ctrl-C's KeyboardInterrupt."""

    def __init__(self, signum: int):
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


def signum_of(err: KeyboardInterrupt) -> int:
    """The signal behind an interruption: a :class:`Terminated`'s, else SIGINT (Ctrl-C)."""
    return getattr(err, "signum", signal.SIGINT)


def interruption(signum: int = signal.SIGINT) -> str:
    """The head of a stopped command's one line: ``interrupted`` (Ctrl-C) or ``terminated (SIGTERM)``."""
    return "interrupted" if signum == signal.SIGINT else f"terminated ({signal.Signals(signum).name})"


def interruption_cause(signum: int = signal.SIGINT) -> str:
    """What stopped a command, for its INCOMPLETE marker: ``interrupted (Ctrl-C)`` or ``terminated (SIGTERM)``."""
    return "interrupted (Ctrl-C)" if signum == signal.SIGINT else interruption(signum)


def signal_exit_code(signum: int = signal.SIGINT) -> int:
    """128 + the signal's number: 130 Ctrl-C, 143 SIGTERM, 129 SIGHUP (what a shell shows for a killed process)."""
    return 128 + signum


def _raise_terminated(signum: int, frame) -> None:
    raise Terminated(signum)


@contextlib.contextmanager
def stop_signals_interrupt() -> Iterator[None]:
    """Within: SIGTERM and SIGHUP raise :class:`Terminated` in the main thread (the previous handlers are put
    back at the end). A signal that was ignored stays ignored (``nohup``); outside the main thread, nothing."""
    previous = {}
    if threading.current_thread() is threading.main_thread():
        for sig in (getattr(signal, name) for name in STOP_SIGNALS if hasattr(signal, name)):
            if signal.getsignal(sig) is not signal.SIG_IGN:
                previous[sig] = signal.signal(sig, _raise_terminated)
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler if handler is not None else signal.SIG_DFL)


def interruption_behind(err: BaseException) -> BaseException:
    """``err``, or the Ctrl-C / SIGTERM / SIGHUP behind it: a signal whose handler raised while compiled code was
    running (numba's dispatcher) surfaces as "SystemError: ... returned a result with an exception set" with the
    KeyboardInterrupt as its cause; the run was interrupted, not broken."""
    cause = err
    while isinstance(cause, SystemError) and isinstance(cause.__cause__ or cause.__context__, BaseException):
        cause = cause.__cause__ or cause.__context__
    return cause if isinstance(cause, KeyboardInterrupt) else err


def describe_os_error(err: OSError) -> str:
    """``path: what happened`` for an OSError, e.g. ``runs/x/tracks.parquet: no space left on device``."""
    what = os.strerror(err.errno).lower() if err.errno else one_line(err) or type(err).__name__
    if err.errno == errno.ENOSPC:
        what = "no space left on device (free some space and run again)"
    where = err.filename if err.filename is not None else ""
    return f"{where}: {what}" if where else what


def exit_code(err: BaseException) -> int:
    if isinstance(err, KeyboardInterrupt):
        return signal_exit_code(signum_of(err))
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
        print(interruption(signum_of(err)), file=sys.stderr)
    else:
        print(f"error: {message(err)}", file=sys.stderr)
    return exit_code(err)


def guarded(func: Callable[[Any], int], args: Any, debug: bool = False) -> int:
    """``func(args)``, with every exception (incl. Ctrl-C, SIGTERM and SIGHUP) reported by :func:`report`."""
    with stop_signals_interrupt():
        try:
            return func(args)
        except BrokenPipeError:  # the reader left (`testbed trackers | head`): nothing to report, as for `ls | head`
            return quiet_stdout()
        except (Exception, KeyboardInterrupt) as err:  # noqa: BLE001 - the last resort: one line, never a traceback
            return report(err, debug)


def quiet_stdout() -> int:
    """After a broken pipe on stdout: point stdout at /dev/null (so the interpreter's flush at exit cannot fail
    again, as the Python documentation's 'Note on SIGPIPE' advises) and return exit code 0."""
    with contextlib.suppress(OSError, ValueError):
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    return 0
