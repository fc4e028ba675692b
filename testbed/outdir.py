"""Output folders of ``testbed run`` and ``testbed perception``: checked before any work, written in a fresh
hidden sibling folder and moved into place at the end, so a folder never mixes the files of two runs.

    stage = Staging("runs/x", RUN_FILES)  # ConfigError (exit 2) if the folder cannot be used
    ...write into stage.tmp...            # runs/.x.partial-<pid>
    stage.commit()                        # success: stage.tmp replaces runs/x
    stage.abandon("why")                  # failure or Ctrl-C: what was written replaces runs/x, with INCOMPLETE

The folder may be missing, empty, or the output of an earlier run (every entry one the command writes); a
folder holding anything else is refused, never deleted. Partial folders of processes that died (``kill -9``)
are removed by the next command that writes into the same parent folder.
"""
from __future__ import annotations

import contextlib
import fnmatch
import os
import re
import shutil
from pathlib import Path
from typing import Callable

from .config import ConfigError
from .errors import RunError

INCOMPLETE = "INCOMPLETE"
_TMP_FILE = ".*.tmp-*"  # a write_atomic temporary (a crash between write and rename)
RUN_FILES = ("run.rrd", "scores.json", "*.parquet", INCOMPLETE, _TMP_FILE)
REPORT_FILES = ("report.md", "summary.json", "*.png", INCOMPLETE, _TMP_FILE)
_STALE = re.compile(r"^\..+\.(partial|old)-(\d+)$")


def write_atomic(path: Path, write: Callable[[Path], None]) -> None:
    """``write(tmp)`` for a hidden temporary file beside ``path``, then rename it to ``path``: a reader (or a
    crash, or a full disk) sees the previous file or the complete new one, never a half-written one. An OSError
    without a file name (pyarrow's) is raised again naming ``path``."""
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    try:
        write(tmp)
        os.replace(tmp, path)
    except BaseException as err:
        with contextlib.suppress(OSError):
            tmp.unlink()
        if isinstance(err, OSError) and err.errno and err.filename is None:
            raise OSError(err.errno, os.strerror(err.errno), str(path)) from err
        raise


def pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's live process
        return True
    return True


def remove_stale(parent: Path) -> list[Path]:
    """Remove the ``.<name>.partial-<pid>`` and ``.<name>.old-<pid>`` folders in ``parent`` whose process is
    gone; return them."""
    removed = []
    try:
        entries = list(os.scandir(parent))
    except OSError:
        return removed
    for entry in entries:
        m = _STALE.match(entry.name)
        if m and entry.is_dir(follow_symlinks=False) and int(m.group(2)) != os.getpid() \
                and not pid_alive(int(m.group(2))):
            shutil.rmtree(entry.path, ignore_errors=True)
            removed.append(Path(entry.path))
    return removed


def foreign_entries(folder: Path, patterns: tuple[str, ...]) -> list[str]:
    """Names in ``folder`` that are not plain files matching ``patterns`` (sorted; [] for a run's folder)."""
    out = []
    for entry in os.scandir(folder):
        ours = entry.is_file(follow_symlinks=False) and any(fnmatch.fnmatchcase(entry.name, p) for p in patterns)
        if not ours:
            out.append(entry.name + ("/" if entry.is_dir(follow_symlinks=False) else ""))
    return sorted(out)


def _unusable(path: Path, shown: str, patterns: tuple[str, ...]) -> str | None:
    """Why ``path`` cannot be an output folder, or None."""
    if not path.name:
        return f"{shown} is not a folder a run can be moved into; choose another --out"
    if path.exists() and not path.is_dir():
        return f"{shown} is a file, not a folder; choose another --out"
    if path.is_dir():
        try:
            other = foreign_entries(path, patterns)
        except OSError as err:
            return f"{shown}: cannot list it ({os.strerror(err.errno).lower() if err.errno else err})"
        if other:
            listed = ", ".join(other[:3]) + (", ..." if len(other) > 3 else "")
            return f"{shown} holds other files ({listed}); choose another --out (a run replaces only an empty " \
                   f"folder or the folder of an earlier run)"
    return None


class Staging:
    """A fresh temporary folder beside ``out`` (``.<name>.partial-<pid>``), moved onto ``out`` at the end.

    Raises ConfigError (``key``, exit 2) when ``out`` is a file, holds files other than ``patterns``, or its
    parent folder cannot be created or written; the message shows ``out`` as given."""

    def __init__(self, out: str | Path, patterns: tuple[str, ...] = RUN_FILES, key: str = "--out"):
        if not str(out).strip():
            raise ConfigError(key, "is empty; give a folder path")
        self.shown = str(out).rstrip("/") or str(out)
        self.patterns = patterns
        self.key = key
        self.path = Path(out).expanduser().resolve()
        why = _unusable(self.path, self.shown, patterns)
        if why:
            raise ConfigError(key, why)
        parent = self.path.parent
        above = next(p for p in (parent, *parent.parents) if p.exists() or p.is_symlink())
        if not above.is_dir():
            raise ConfigError(key, f"cannot create {self.shown}: {above} is a file, not a folder; choose another --out")
        try:
            parent.mkdir(parents=True, exist_ok=True)
            remove_stale(parent)
            self.tmp = parent / f".{self.path.name}.partial-{os.getpid()}"
            if self.tmp.exists():
                shutil.rmtree(self.tmp)
            self.tmp.mkdir()
        except OSError as err:
            what = os.strerror(err.errno).lower() if err.errno else str(err)
            raise ConfigError(key, f"cannot write a folder in {parent} ({what}); choose another --out") from None

    def shown_text(self, text: str) -> str:
        """``text`` with the temporary folder's path replaced by the folder as given."""
        return text.replace(str(self.tmp), self.shown)

    def written(self) -> list[str]:
        """The files written so far (sorted names)."""
        try:
            return sorted(e.name for e in os.scandir(self.tmp) if not fnmatch.fnmatchcase(e.name, _TMP_FILE))
        except OSError:
            return []

    def commit(self) -> Path:
        """Move the finished output onto ``out`` (replacing an earlier run's folder); return ``out``."""
        self._swap()
        return self.path

    def abandon(self, reason: str) -> Path:
        """Mark what was written INCOMPLETE (with ``reason``) and move it onto ``out``; return where it is
        (the temporary folder if it could not be moved)."""
        try:
            (self.tmp / INCOMPLETE).write_text(reason.rstrip() + "\n")
        except OSError:  # a full disk: an empty marker still says it
            with contextlib.suppress(OSError):
                (self.tmp / INCOMPLETE).touch()
        try:
            self._swap()
        except (OSError, RunError):
            return self.tmp
        return self.path

    def discard(self) -> None:
        """Remove the temporary folder (nothing to keep)."""
        shutil.rmtree(self.tmp, ignore_errors=True)

    def _swap(self) -> None:
        why = _unusable(self.path, self.shown, self.patterns)  # files added to it during the run are kept
        if why:
            raise RunError(f"{why}; this run is in {self.tmp}")
        old = None
        if self.path.exists():
            old = self.path.parent / f".{self.path.name}.old-{os.getpid()}"
            os.replace(self.path, old)
        os.replace(self.tmp, self.path)
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
