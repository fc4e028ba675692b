"""``testbed view RUN [--web] [--port N] [--at SECONDS | --event N]``: the rerun viewer on a run's recording.

The recording is read back first (a corrupt or truncated file is one line, exit 2); the port is checked free;
the viewer process dies with testbed (PR_SET_PDEATHSIG) and SIGTERM / SIGINT / SIGHUP are passed on to it.
rerun's own INFO lines are off (``RUST_LOG=warn`` unless set): testbed prints the one line that matters, the
web viewer's address. ``--at`` opens the recording at that simulated time, paused (testbed/recording/
timecursor.py); ``--event N`` at the time of the run's event N (events.parquet). On a machine's first use, rerun's analytics are switched off (``rerun analytics disable``) so
its banner does not appear; an existing choice is left alone.
"""
from __future__ import annotations

import argparse
import contextlib
import math
import threading
import urllib.parse
import warnings
import os
import subprocess
import sys
from pathlib import Path

from ..config import ConfigError
from ..common.errors import one_line
from .rrd import rerun_exe


def cmd_view(args: argparse.Namespace) -> int:
    path = Path(args.run_dir)
    rrd = path if path.suffix == ".rrd" else path / "run.rrd"
    if not rrd.is_file():
        raise ConfigError("", f"{rrd}: no recording (run `testbed run SCENARIO --out {path}` first)")
    event = getattr(args, "event", None)
    if event is not None and getattr(args, "at", None) is not None:
        raise ConfigError("--event", "give --at or --event, not both")
    at_event = event_time(rrd.parent, event) if event is not None else None  # before the file is read
    end_s = _check_recording(rrd)
    at = getattr(args, "at", None) if at_event is None else at_event
    if at is not None and at > end_s + 1e-9:
        raise ConfigError("--at", f"{at:g} s is past the end of the recording ({rrd} ends at {end_s:g} s); "
                                  f"allowed: 0..{end_s:g}")
    incomplete = rrd.parent / "INCOMPLETE"
    if incomplete.is_file():
        reason = one_line(incomplete.read_text(errors="replace")) or "no reason recorded"
        print(f"note: {rrd.parent} holds an incomplete run ({reason})", file=sys.stderr)
    headless = sys.platform.startswith("linux") and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))
    if headless and not args.web:
        print("no display found: serving the web viewer on 127.0.0.1 instead (Ctrl-C to stop)", file=sys.stderr)
    exe = rerun_exe()
    env = dict(os.environ)
    env.setdefault("RUST_LOG", "warn")  # rerun's INFO lines (telemetry, "Loading ...", "Listening ...") off
    _rerun_analytics_off(exe, env)
    cmd, on_start = (_web_viewer if args.web or headless else _native_viewer)(exe, rrd, args.port, at)
    return _supervise(cmd, env, on_start)


def _web_viewer(exe: str, rrd: Path, port: int | None, at: float | None):
    """The ``rerun --serve-web`` command, and what to do once it runs: print the page's address (and with
    ``at``, serve the page with its start time on ``port``, rerun's own page on an internal one)."""
    port = port if port is not None else WEB_VIEWER_PORT
    _require_free_port(port)
    grpc = _free_port()
    inner = port if at is None else _free_port()
    cmd = [exe, "--serve-web", "--bind", "127.0.0.1", "--web-viewer-port", str(inner), "--port", str(grpc), str(rrd)]
    url = f"http://127.0.0.1:{port}/?url=" + urllib.parse.quote(f"rerun+http://127.0.0.1:{grpc}/proxy", safe="")

    def on_start() -> None:
        if at is not None:
            from .webpage import serve_page

            serve_page(port, inner, at)
        when = f" (opening at {at:g} s, paused)" if at is not None else ""
        print(f"web viewer{when}, Ctrl-C to stop: {url}", flush=True)

    return cmd, on_start


def _native_viewer(exe: str, rrd: Path, port: int | None, at: float | None):
    """The native viewer's command, and (with ``at``) a thread that moves its cursor once the file is in."""
    if port is not None:
        _require_free_port(port)
    elif at is not None:
        port = _free_port()  # the cursor is moved through the viewer's own gRPC server
    cmd = [exe, *(["--port", str(port)] if port is not None else []), str(rrd)]

    def on_start() -> None:
        if at is None:
            return
        from .timecursor import seek_native

        def seek() -> None:
            if not seek_native(port, at):
                print(f"warning: the viewer did not take the start time {at:g} s", file=sys.stderr)

        threading.Thread(target=seek, name="testbed-view-seek", daemon=True).start()

    return cmd, on_start


def at_arg(text: str) -> float:
    """``--at SECONDS``: a finite time >= 0 (checked against the recording's end once it is read)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected seconds >= 0, got {text!r}") from None
    if not math.isfinite(value) or value < 0:
        raise argparse.ArgumentTypeError(f"expected seconds >= 0, got {text}")
    return value


def event_arg(text: str) -> int:
    """``--event N``: an event number >= 1 (checked against the run's events.parquet)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an event number >= 1, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected an event number >= 1, got {value}")
    return value


def event_time(folder: Path, n: int) -> float:
    """The time [s] of event ``n`` (1-based, testbed.scoring.events) of the run in ``folder``, after printing it;
    ConfigError (one line) without an events.parquet or when there is no event ``n``."""
    import pandas as pd

    from ..scoring.events import describe_event

    path = Path(folder) / "events.parquet"
    if not path.is_file():
        raise ConfigError("--event", f"{path}: no events table (run the scenario again with this version)")
    try:
        ev = pd.read_parquet(path)
    except Exception as err:  # noqa: BLE001 - a damaged file is the option's error
        raise ConfigError("--event", f"{path}: cannot be read ({type(err).__name__})") from None
    if not 1 <= n <= len(ev):
        allowed = f"1..{len(ev)}" if len(ev) else "none: the run has no event"
        raise ConfigError("--event", f"{n}: no such event in {path}; allowed: {allowed}")
    row = ev.iloc[n - 1]
    print(f"event {n} at {float(row['time']):.1f} s: {describe_event(row)}", file=sys.stderr)
    return float(row["time"])


WEB_VIEWER_PORT = 9090  # rerun's default web viewer port
STOP_SIGNALS = ("SIGTERM", "SIGINT", "SIGHUP")
STOP_GRACE_S = 5.0  # seconds the viewer is given to exit after SIGTERM before it is killed


def _check_recording(rrd: Path) -> float:
    """The last ``sim_time`` [s] of ``rrd``; ConfigError unless it reads back as a rerun recording with data
    (rerun's own reader; a whole file is streamed, about 50 ms per 100 MB)."""
    from rerun.chunk import RrdReader

    chunks, end_ns = 0, 0
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # "no footer/manifest": a long run's recording, readable
            for chunk in RrdReader(str(rrd)).stream():
                chunks += 1
                if "sim_time" in chunk.timeline_names:
                    times = chunk.to_record_batch().column("sim_time").cast("int64").to_numpy(zero_copy_only=False)
                    end_ns = max(end_ns, int(times.max())) if len(times) else end_ns
    except BaseException as err:  # noqa: BLE001 - rerun raises RuntimeError, ValueError, PanicException
        if isinstance(err, KeyboardInterrupt | SystemExit):
            raise
        raise ConfigError("", f"{rrd}: not a readable rerun recording ({one_line(err) or type(err).__name__}); "
                          f"run the scenario again") from None
    if chunks == 0:
        raise ConfigError("", f"{rrd}: the recording holds no data; run the scenario again")
    return end_ns / 1e9


def port_arg(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a port number 1-65535, got {text!r}") from None
    if not 1 <= value <= 65535:
        raise argparse.ArgumentTypeError(f"expected a port number 1-65535, got {value}")
    return value


def _require_free_port(port: int) -> None:
    """ConfigError if something listens on 127.0.0.1:``port`` (bound as rerun binds it, SO_REUSEADDR)."""
    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            raise ConfigError("--port", f"port {port} is in use (another `testbed view`?): pass --port with "
                              f"a free one") from None


def _free_port() -> int:
    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _rerun_config_dir() -> Path | None:
    if sys.platform.startswith("linux"):
        return Path(os.environ.get("XDG_CONFIG_HOME") or Path.home() / ".config") / "rerun"
    if sys.platform == "darwin":
        return Path.home() / "Library" / "Application Support" / "rerun"
    return None


def _rerun_analytics_off(exe: str, env: dict) -> None:
    """rerun 0.41 reads no RERUN_ANALYTICS variable: the first time its CLI runs (no analytics.json in its
    config folder) it prints a 20-line analytics banner and turns analytics on. The first time, opt out as
    `rerun analytics disable` does (its banner swallowed) and say so in one line; a choice already made (the
    file exists) is left alone."""
    folder = _rerun_config_dir()
    if folder is None or (folder / "analytics.json").exists():
        return
    try:
        subprocess.run([exe, "analytics", "disable"], env=env, capture_output=True, timeout=30, check=False)
    except (OSError, subprocess.SubprocessError):
        return
    print("rerun analytics turned off (`rerun analytics enable` turns them on)", file=sys.stderr)


def _die_with_parent():
    """A preexec_fn for Linux: the kernel SIGKILLs the child when we die, even by SIGKILL (libc loaded
    here, before the fork)."""
    if not sys.platform.startswith("linux"):
        return None
    import ctypes
    import signal

    try:
        prctl = ctypes.CDLL(None, use_errno=True).prctl
    except (OSError, AttributeError):
        return None
    parent = os.getpid()

    def preexec() -> None:
        prctl(1, signal.SIGKILL, 0, 0, 0)  # PR_SET_PDEATHSIG = 1
        if os.getppid() != parent:  # we died before the request took effect
            os._exit(1)

    return preexec


def _supervise(cmd: list[str], env: dict, on_start=None) -> int:
    """Run the viewer ``cmd`` until it exits (``on_start()`` once it is started). SIGTERM, SIGINT and SIGHUP
    to us are passed on as SIGTERM and the viewer is waited for (killed after ``STOP_GRACE_S``); if we are
    killed, the kernel kills it. Returns 128 + the signal, or 1 with one line if the viewer failed."""
    import signal
    import time

    proc = subprocess.Popen(cmd, env=env, preexec_fn=_die_with_parent())
    if on_start is not None:
        on_start()
    got: list[tuple[int, float]] = []  # (signal, when)

    def forward(signum, _frame) -> None:
        got.append((signum, time.monotonic()))
        with contextlib.suppress(ProcessLookupError):
            proc.send_signal(signal.SIGTERM)

    sigs = [getattr(signal, name) for name in STOP_SIGNALS if hasattr(signal, name)]
    previous = {sig: signal.signal(sig, forward) for sig in sigs}
    try:
        while True:
            try:
                rc = proc.wait(timeout=0.5)
                break
            except subprocess.TimeoutExpired:
                if got and time.monotonic() - got[0][1] > STOP_GRACE_S:
                    proc.kill()
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    if got:
        if got[0][0] == signal.SIGINT:
            print("interrupted: viewer stopped", file=sys.stderr)
        return 128 + got[0][0]
    if rc != 0:
        print(f"error: the rerun viewer exited with code {rc} (its messages are above)", file=sys.stderr)
        return 1
    return 0

