"""Writing files in output folders (run, campaign, perception, reproduce) without following symbolic links.

Every file the tool writes there (a lock, a temporary, a final output) is opened with ``O_NOFOLLOW``, and a
temporary is created with ``O_EXCL`` too. A symbolic link found at one of those names is refused with one
line naming it (:class:`~testbed.config.strict.ConfigError`, exit 2); its target is never written, truncated or
removed. A final name is checked as well, although ``os.replace`` would only replace the link itself: a link
where the tool writes means the folder is not what it looks like.

    write_text(out / "summary.md", text)        # temporary beside it, then renamed (atomic)
    save_figure(fig, out / "pd.png", dpi=110)   # matplotlib writes into a file this module opened
    with atomic_path(out / "t.parquet") as tmp:  # for writers that take a path (pyarrow)
        pq.write_table(table, tmp)

A temporary is ``.<name>.tmp-<pid>``: a crash between writing and renaming leaves at most one per name and
process; the next writer with that pid replaces it.
"""
from __future__ import annotations

import contextlib
import errno
import os
import time
from pathlib import Path
from typing import Iterator

from ..config import ConfigError


def link_error(path: str | Path, key: str = "", shown: str | None = None) -> ConfigError:
    """The one-line error for a symbolic link at ``path`` (named ``shown``, default ``path``), where the tool
    was about to write."""
    try:
        target = os.readlink(path)
    except OSError:
        target = "?"
    return ConfigError(key, f"{shown or path} is a symbolic link (to {target}); refusing to write through it")


def refuse_link(path: str | Path, key: str = "", shown: str | None = None) -> None:
    """ConfigError if ``path`` is a symbolic link (checked with lstat: never followed)."""
    if os.path.islink(path):
        raise link_error(path, key, shown)


def open_fd(path: str | Path, flags: int, mode: int = 0o644) -> int:
    """``os.open(path, flags)`` with ``O_NOFOLLOW`` and ``O_CLOEXEC``: a symbolic link at ``path`` is a
    ConfigError naming it (other failures stay OSErrors)."""
    try:
        return os.open(path, flags | os.O_NOFOLLOW | os.O_CLOEXEC, mode)
    except OSError as err:
        if err.errno in (errno.ELOOP, errno.EMLINK, errno.EEXIST) and os.path.islink(path):
            raise link_error(path) from None
        raise


def open_write(path: str | Path):
    """``path`` opened for writing (binary, created or truncated), never through a symbolic link."""
    return os.fdopen(open_fd(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC), "wb")


def temp_name(path: str | Path) -> Path:
    """The hidden temporary beside ``path`` that this process writes before renaming it to ``path``."""
    path = Path(path)
    return path.with_name(f".{path.name}.tmp-{os.getpid()}")


def create_temp(path: str | Path) -> Path:
    """Create the empty temporary of ``path`` (``O_EXCL | O_NOFOLLOW``: a new regular file of this process)
    and return its name; a leftover file of a dead process with this pid is replaced, a link refused."""
    tmp = temp_name(path)
    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL
    try:
        fd = open_fd(tmp, flags)
    except FileExistsError:  # not a link (open_fd refused that): a file with our pid in its name is ours
        tmp.unlink()
        fd = open_fd(tmp, flags)
    os.close(fd)
    return tmp


def fsync_dir(path: str | Path) -> None:
    """Flush a folder's entries (a rename in it) to disk, where the system allows it."""
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


@contextlib.contextmanager
def atomic_path(path: str | Path, fsync: bool = False) -> Iterator[Path]:
    """The name of a new, empty temporary beside ``path``, for a writer that takes a path; renamed onto
    ``path`` when the block ends, removed if it raises. With ``fsync`` the file and then the folder are
    flushed to disk (a crash leaves the old file or the new one, whole). A link at ``path`` or at the
    temporary's name is refused (ConfigError) before anything is written."""
    path = Path(path)
    refuse_link(path)
    tmp = create_temp(path)
    try:
        yield tmp
        if fsync:
            fd = open_fd(tmp, os.O_RDONLY)
            try:
                os.fsync(fd)
            finally:
                os.close(fd)
        refuse_link(path)  # planted while the block wrote
        os.replace(tmp, path)
    except BaseException:  # e.g. a full disk: no half-written temporary left behind
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise
    if fsync:
        fsync_dir(path.parent)


def write_bytes(path: str | Path, data: bytes, fsync: bool = False) -> None:
    """Write ``data`` to ``path`` atomically (see :func:`atomic_path`)."""
    with atomic_path(path, fsync) as tmp, open_write(tmp) as fh:
        fh.write(data)


def write_text(path: str | Path, text: str, fsync: bool = False) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically (see :func:`atomic_path`)."""
    write_bytes(path, text.encode("utf-8"), fsync)


def save_figure(fig, path: str | Path, **savefig_kwargs) -> None:
    """``fig.savefig`` into ``path`` atomically, the format from its suffix (PNG without one)."""
    path = Path(path)
    with atomic_path(path) as tmp, open_write(tmp) as fh:
        fig.savefig(fh, format=path.suffix.lstrip(".") or "png", **savefig_kwargs)


def make_folder(path: str | Path, key: str = "") -> Path:
    """Create the folder ``path`` (and its parents) unless it exists; a symbolic link there is refused."""
    path = Path(path)
    refuse_link(path, key)
    path.mkdir(parents=True, exist_ok=True)
    return path


def try_lock(path: str | Path) -> int | None:
    """Take an exclusive ``flock`` on the file ``path`` (created if missing, never through a symbolic link)
    without waiting and write this process's pid into it: the open descriptor (closing it releases the lock),
    or None while another process holds it. The kernel releases the lock when its process ends, even by
    SIGKILL. A lock file removed by its holder (see :func:`unlock`) is taken afresh under its name."""
    import fcntl

    for _ in range(20):
        fd = open_fd(path, os.O_RDWR | os.O_CREAT)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            return None
        except BaseException:
            os.close(fd)
            raise
        try:
            now, ours = os.stat(path, follow_symlinks=False), os.fstat(fd)
            same = (now.st_dev, now.st_ino) == (ours.st_dev, ours.st_ino)
        except FileNotFoundError:
            same = False
        if same:
            os.ftruncate(fd, 0)
            os.write(fd, f"{os.getpid()}\n".encode())
            return fd
        os.close(fd)  # its holder removed it after we opened it: lock the file now under that name
    raise OSError(errno.EAGAIN, "the lock file keeps being replaced", str(path))


def unlock(fd: int, path: str | Path | None = None) -> None:
    """Release a lock of :func:`try_lock`; with ``path``, first remove the lock file (still holding it)."""
    if path is not None:
        with contextlib.suppress(OSError):
            os.unlink(path)
    os.close(fd)


def lock_holder(path: str | Path) -> str:
    """The pid written in a held lock file ('unknown' if its holder has not written it within a second)."""
    for _ in range(20):
        try:
            fd = open_fd(path, os.O_RDONLY)
            try:
                text = os.read(fd, 64).decode("ascii", "replace").strip()
            finally:
                os.close(fd)
        except (OSError, ConfigError):
            text = ""
        if text.isdigit():
            return text
        time.sleep(0.05)
    return "unknown"
