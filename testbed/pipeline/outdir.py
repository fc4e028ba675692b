"""Output folders of ``testbed run`` and ``testbed perception``: checked before any work, written in a fresh
hidden sibling folder and moved into place at the end, so a folder never mixes the files of two runs.

    stage = Staging("runs/x", RUN_FILES)  # ConfigError (exit 2) if the folder cannot be used or is in use
    ...write into stage.tmp...            # runs/.x.partial-<pid>
    stage.commit()                        # success: stage.tmp replaces runs/x
    stage.abandon("why")                  # failure or Ctrl-C: what was written replaces runs/x, with INCOMPLETE

The folder may be missing, empty, or the output of an earlier run (every entry one the command writes); a
folder holding anything else is refused, never deleted. Partial folders of processes that died (``kill -9``)
are removed by the next command that writes into the same parent folder.

While a command writes ``runs/x`` it holds ``runs/.x.lock`` (``flock``, holding its pid): a second command
writing ``runs/x`` is refused in one line naming that pid, before any work. The lock file sits beside the
folder, since the folder itself is replaced by a rename; it is removed when the command ends, and the one a
killed command leaves (unlocked: the kernel releases a lock when its process dies) is taken and removed by the
next command writing ``runs/x``. No name this module writes (``--out``, the lock, the ``.partial-``/``.old-``
folders, ``INCOMPLETE``, temporaries) is ever followed as a symbolic link (see :mod:`testbed.common.safe_io`).
"""
from __future__ import annotations

import contextlib
import fnmatch
import os
import re
import shutil
from pathlib import Path
from typing import Any, Callable

from ..common import safe_io
from ..config import ConfigError
from ..common.errors import RunError

INCOMPLETE = "INCOMPLETE"
_TMP_FILE = ".*.tmp-*"  # a write_atomic temporary (a crash between write and rename)
RUN_FILES = ("run.rrd", "scores.json", "*.parquet", "timeline.png", "replay.html", "kitti", INCOMPLETE, _TMP_FILE)
"""What a run folder may hold: a run's files and its exports (``testbed export``, e.g. replay.html, kitti/), which a new run
replaces with the folder."""
REPORT_FILES = ("report.md", "summary.json", "*.png", INCOMPLETE, _TMP_FILE)
_STALE = re.compile(r"^\..+\.(partial|old)-(\d+)$")


def write_atomic(path: Path, write: Callable[[Path], None]) -> None:
    """``write(tmp)`` for a new hidden temporary file beside ``path``, then rename it to ``path``: a reader (or a
    crash, or a full disk) sees the previous file or the complete new one, never a half-written one. A symbolic
    link at ``path`` or at the temporary's name is refused (:func:`testbed.common.safe_io.atomic_path`). An OSError
    without a file name (pyarrow's) is raised again naming ``path``."""
    try:
        with safe_io.atomic_path(path) as tmp:
            write(tmp)
    except OSError as err:
        if err.errno and err.filename is None:
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


def _links(folder: Path) -> list[str]:
    """Names of the symbolic links in ``folder`` (sorted)."""
    return sorted(e.name for e in os.scandir(folder) if e.is_symlink())


def _unusable(path: Path, shown: str, patterns: tuple[str, ...]) -> str | None:
    """Why ``path`` cannot be an output folder, or None."""
    if not path.name:
        return f"{shown} is not a folder a run can be moved into; choose another --out"
    if path.is_symlink():
        return f"{safe_io.link_error(path, shown=shown)}; choose another --out"
    if path.exists() and not path.is_dir():
        return f"{shown} is a file, not a folder; choose another --out"
    if path.is_dir():
        try:
            links, other = _links(path), foreign_entries(path, patterns)
        except OSError as err:
            return f"{shown}: cannot list it ({os.strerror(err.errno).lower() if err.errno else err})"
        if links:
            return f"{safe_io.link_error(path / links[0], shown=f'{shown}/{links[0]}')}; choose another --out " \
                   f"(a run replaces only an empty folder or the folder of an earlier run)"
        if other:
            listed = ", ".join(other[:3]) + (", ..." if len(other) > 3 else "")
            return f"{shown} holds other files ({listed}); choose another --out (a run replaces only an empty " \
                   f"folder or the folder of an earlier run)"
    return None


class Staging:
    """A fresh temporary folder beside ``out`` (``.<name>.partial-<pid>``), moved onto ``out`` at the end; ``out``
    is locked (``.<name>.lock`` beside it) from the start until :meth:`commit`, :meth:`abandon` or
    :meth:`discard`.

    Raises ConfigError (``key``, exit 2) when ``out`` is a file or a symbolic link, holds files other than
    ``patterns``, is being written by another process, or its parent folder cannot be created or written;
    the message shows ``out`` as given."""

    def __init__(self, out: str | Path, patterns: tuple[str, ...] = RUN_FILES, key: str = "--out"):
        if not str(out).strip():
            raise ConfigError(key, "is empty; give a folder path")
        self.shown = str(out).rstrip("/") or str(out)
        self.patterns = patterns
        self.key = key
        given = Path(out).expanduser()
        if given.is_symlink():  # resolving it would write (and replace) the folder it points to
            raise ConfigError(key, f"{safe_io.link_error(given, shown=self.shown)}; choose another --out")
        self.path = given.resolve()
        why = _unusable(self.path, self.shown, patterns)
        if why:
            raise ConfigError(key, why)
        parent = self.path.parent
        above = next(p for p in (parent, *parent.parents) if p.exists() or p.is_symlink())
        if not above.is_dir():
            raise ConfigError(key, f"cannot create {self.shown}: {above} is a file, not a folder; choose another --out")
        self.tmp = parent / f".{self.path.name}.partial-{os.getpid()}"
        self.lock_path = parent / f".{self.path.name}.lock"
        self._lock_fd: int | None = None
        self._write_guarded(lambda: parent.mkdir(parents=True, exist_ok=True))
        self._lock()
        try:
            self._prepare()
        except BaseException:
            self._release()
            raise

    def _beside(self, path: Path) -> str:
        """``path`` (a sibling of ``out``) as the user would write it."""
        return str(Path(self.shown).parent / path.name)

    def _write_guarded(self, action: Callable[[], Any]) -> Any:
        """``action()``, an OSError a one-line ConfigError saying the parent folder cannot be written."""
        try:
            return action()
        except OSError as err:
            what = os.strerror(err.errno).lower() if err.errno else str(err)
            raise ConfigError(self.key, f"cannot write a folder in {self.path.parent} ({what}); choose another "
                              "--out") from None

    def _lock(self) -> None:
        """Take ``.<name>.lock`` (ConfigError naming the holder's pid while another process holds it)."""
        safe_io.refuse_link(self.lock_path, self.key, shown=self._beside(self.lock_path))
        fd = self._write_guarded(lambda: safe_io.try_lock(self.lock_path))
        if fd is None:
            raise ConfigError(self.key, f"{self.shown} is being written by another testbed process (pid "
                              f"{safe_io.lock_holder(self.lock_path)}); wait for it to end or choose another --out")
        self._lock_fd = fd

    def _release(self) -> None:
        """Remove and release the lock (once)."""
        if self._lock_fd is not None:
            safe_io.unlock(self._lock_fd, self.lock_path)
            self._lock_fd = None

    def _prepare(self) -> None:
        """Check ``out`` again (now that it is locked), remove dead processes' partial folders and make a fresh
        temporary folder; a symbolic link at the temporary or ``.old-`` name is refused, never followed."""
        why = _unusable(self.path, self.shown, self.patterns)
        if why:
            raise ConfigError(self.key, why)
        for name in (self.tmp, self._old()):
            safe_io.refuse_link(name, self.key, shown=self._beside(name))

        def fresh() -> None:
            remove_stale(self.path.parent)
            for name in (self.tmp, self._old()):  # this pid's, left by a dead process with the same pid
                if name.exists():
                    shutil.rmtree(name)
            self.tmp.mkdir()

        self._write_guarded(fresh)

    def _old(self) -> Path:
        return self.path.parent / f".{self.path.name}.old-{os.getpid()}"

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
        try:
            self._swap()
        finally:
            self._release()
        return self.path

    def abandon(self, reason: str) -> Path:
        """Mark what was written INCOMPLETE (with ``reason``) and move it onto ``out``; return where it is
        (the temporary folder if it could not be moved). A symbolic link planted at ``INCOMPLETE`` is left
        alone, and so is the output: RunError saying both."""
        try:
            self._mark(reason)
        except ConfigError as err:
            self._release()
            raise RunError(f"{reason.rstrip()} ({err}; what was written is kept in {self.tmp}/, not marked "
                           f"INCOMPLETE)") from None
        try:
            self._swap()
        except (OSError, RunError):
            return self.tmp
        finally:
            self._release()
        return self.path

    def _mark(self, reason: str) -> None:
        """Write the INCOMPLETE marker (never through a link); on a full disk an empty marker still says it."""
        marker = self.tmp / INCOMPLETE
        try:
            with safe_io.open_write(marker) as fh:
                fh.write((reason.rstrip() + "\n").encode("utf-8"))
        except OSError:
            with contextlib.suppress(OSError):
                os.close(safe_io.open_fd(marker, os.O_WRONLY | os.O_CREAT))

    def discard(self) -> None:
        """Remove the temporary folder (nothing to keep)."""
        shutil.rmtree(self.tmp, ignore_errors=True)
        self._release()

    def _swap(self) -> None:
        why = _unusable(self.path, self.shown, self.patterns)  # files added to it during the run are kept
        if why:
            raise RunError(f"{why}; this run is in {self.tmp}")
        old = None
        if self.path.exists():
            old = self._old()
            os.replace(self.path, old)
        os.replace(self.tmp, self.path)
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
