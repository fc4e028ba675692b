"""rerun's command-line tool: finding its binary, and compacting a finished recording.

A run sends its frames as it goes (rerun's batcher, every :data:`~testbed.recording.recorder.BATCHING` tick)
and its per-track series every few seconds of simulated time, so a viewer following a live run sees them
soon; the file then holds many small chunks (23,339 for the 427 s highway benchmark at the default level).
The web viewer's work grows with the number of chunks: that file made the page unresponsive from 202 s and
it had not shown the last frame after 7 minutes; compacted (762-824 chunks, ``rerun rrd optimize``, 3 s) it
showed the last frame 14-29 s after the page was opened in 4 of 7 tries (benchmarks/bench_web_viewer.py,
README; the other 3 and the viewer's memory limit: ``record.max_lidar_frames``, testbed/recording/levels.py).
"""
from __future__ import annotations

import contextlib
import os
import re
import subprocess
import sys
from pathlib import Path

from ..common.safe_io import create_temp, refuse_link
from ..config import ConfigError

ANSI = re.compile(r"\x1b\[[0-9;]*m")  # rerun colours its log lines
SUMMARY = re.compile(r"Chunk count ([\d\s]+?) -> ([\d\s]+?) \(")  # thousands split by a (narrow) space
"""The line of ``rerun rrd optimize``'s log (at INFO) that counts the chunks before and after. It exits with 0
on input it cannot decode, writing an empty recording: a compaction that read no chunk is not kept."""


def rerun_exe() -> str:
    """The rerun binary itself (``RERUN_CLI_PATH`` if set): the ``rerun`` script of the venv is a Python
    wrapper that would sit between us and the viewer's server, and does not pass signals on."""
    if os.environ.get("RERUN_CLI_PATH"):
        return os.environ["RERUN_CLI_PATH"]
    try:
        import rerun_cli

        exe = Path(rerun_cli.__file__).parent / ("rerun.exe" if sys.platform.startswith("win") else "rerun")
        if exe.is_file():
            return str(exe)
    except ImportError:
        pass
    import shutil

    return shutil.which("rerun") or str(Path(sys.executable).parent / "rerun")


class Compaction:
    """``rerun rrd optimize`` of the recording ``path`` into a temporary beside it, started at once in its own
    process (it merges the chunks and adds the footer that long runs are written without); :meth:`wait` puts
    the result in place of the original. Peak memory about three times the file's size; about 1 s per 100 MB.
    """

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self.size = self.path.stat().st_size
        self.tmp: Path | None = None
        self.proc: subprocess.Popen | None = None
        self.failed: str | None = None
        log = f"{os.environ.get('RUST_LOG') or 'warn'},rerun::commands::rrd::merge_optimize=info"  # for SUMMARY
        try:
            refuse_link(self.path)
            self.tmp = create_temp(self.path)  # a new file of ours (O_EXCL, O_NOFOLLOW): rerun writes into it
            self.proc = subprocess.Popen([rerun_exe(), "rrd", "optimize", str(self.path), "-o", str(self.tmp)],
                                         env=dict(os.environ, RUST_LOG=log), stdin=subprocess.DEVNULL,
                                         stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        except OSError as err:
            self.failed = f"rerun rrd optimize: {type(err).__name__}: {err}"
            self._drop()

    def wait(self) -> str | None:
        """Wait for it (at most 60 s + 1 s per 5 MB) and rename the compacted file onto the original. Returns
        None when done, else why not: the original is then kept as it was."""
        if self.proc is None:
            return self.failed
        proc, self.proc = self.proc, None
        try:
            _, err = proc.communicate(timeout=60 + self.size / 5e6)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.communicate()
            self._drop()
            return "rerun rrd optimize took too long"
        except BaseException:  # interrupted: the original stays
            proc.kill()
            proc.wait()
            self._drop()
            raise
        counts = SUMMARY.search(err)
        if proc.returncode:
            lines = [ln.strip() for ln in ANSI.sub("", err).splitlines() if ln.strip()]
            why = f"rerun rrd optimize exited with {proc.returncode}" + (f": {lines[-1]}" if lines else "")
        elif not counts or 0 in (int(re.sub(r"\D", "", c)) for c in counts.groups()):
            why = "rerun rrd optimize read no chunk from it"
        else:
            try:
                refuse_link(self.path)  # planted while it ran
                os.replace(self.tmp, self.path)
                return None
            except (OSError, ConfigError) as err_:
                why = f"{type(err_).__name__}: {err_}"
        self._drop()
        return why

    def cancel(self) -> None:
        """Stop it (if running) and remove its temporary; the original stays as it was."""
        if self.proc is not None:
            self.proc.kill()
            self.proc.wait()
            self.proc = None
            self.failed = "cancelled"
        self._drop()

    def _drop(self) -> None:
        if self.tmp is not None:
            with contextlib.suppress(OSError):
                self.tmp.unlink()
            self.tmp = None


def compact(path: str | Path) -> str | None:
    """Compact the recording ``path`` in place (:class:`Compaction`) and wait: None when done, else why not
    (the original is then kept as it was)."""
    return Compaction(path).wait()
