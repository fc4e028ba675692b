"""Reading the files a user names: scenario and campaign TOML files, shipped ones by their bare name, size-checked
and strictly decoded (one-line ConfigErrors naming the file)."""
from __future__ import annotations

import codecs
import os
import tomllib
from pathlib import Path

from .limits import check
from .strict import ConfigError, one_line, show_path

SHIPPED = Path(__file__).resolve().parents[1] / "_shipped"
"""Where the shipped scenario and campaign files are, inside the package: ``_shipped/scenarios`` and
``_shipped/campaigns``. In a checkout (and an editable install) these are relative symbolic links to the
repository's ``scenarios/`` and ``campaigns/``; a wheel or a plain ``pip install`` carries the files themselves
(package data, ``[tool.setuptools.package-data]`` in pyproject.toml). :func:`shipped_dir` is the one lookup."""
SHIPPED_KINDS = ("scenario", "campaign")


def shipped_dir(kind: str) -> Path:
    """The folder of the shipped files of ``kind`` ("scenario" or "campaign"): the repository's ``scenarios/``
    or ``campaigns/`` in a checkout, the package's copy in an installed package. Every lookup of a shipped file by
    its name goes through here (the folder may be missing in a broken installation: see :func:`shipped_names`)."""
    if kind not in SHIPPED_KINDS:
        raise ValueError(f"kind must be one of {SHIPPED_KINDS}, not {kind!r}")
    return (SHIPPED / f"{kind}s").resolve()


def shipped_names(kind: str) -> list[str]:
    """The names of the shipped files of ``kind`` ("scenario" or "campaign"), sorted; a one-line ConfigError when
    the installation has lost them (a build that left out the package data), never an empty list."""
    folder = shipped_dir(kind)
    names = sorted(p.stem for p in folder.glob("*.toml")) if folder.is_dir() else []
    if not names:
        raise ConfigError("", f"this installation of roadtrack has no shipped {kind}s (nothing in "
                          f"{show_path(folder)}); reinstall it (pip install roadtrack, or pip install -e . in a "
                          "checkout)")
    return names


def find_file(path: str | Path, kind: str) -> Path:
    """``path`` if it is a file, else the shipped ``<path>.toml`` of ``kind`` (:func:`shipped_dir`) when ``path`` is
    a bare name.

    ConfigError (one line) for a missing file, a directory, a path with a NUL character or one the system
    refuses (too long). ``kind``: "scenario" or "campaign", for the lookup and the messages.
    """
    shipped = shipped_dir(kind)
    text, shown = str(path), show_path(path)
    if "\x00" in text:
        raise ConfigError("", f"{shown}: a path cannot contain a NUL character")
    candidate = Path(text)
    try:
        if candidate.is_file():
            return candidate
        named = shipped / f"{text}.toml"
        if candidate.suffix == "" and "/" not in text and named.is_file():
            return named
        if candidate.is_dir():
            raise ConfigError("", f"{shown}: is a directory; expected a {kind} file (.toml)")
        if candidate.exists():
            raise ConfigError("", f"{shown}: not a regular file; expected a {kind} file (.toml)")
    except OSError as err:  # ENAMETOOLONG, ELOOP, EACCES on a parent ...
        what = os.strerror(err.errno).lower() if err.errno else type(err).__name__
        raise ConfigError("", f"{shown}: {what}") from None
    raise ConfigError("", f"{shown}: no such {kind} file (shipped: {', '.join(shipped_names(kind))})")


def read_toml_file(path: Path) -> dict:
    """The TOML dict of file ``path``. Unreadable, oversized, non-UTF-8, binary or malformed files raise a
    one-line ConfigError naming the file (a UTF-8 byte-order mark is accepted)."""
    shown = show_path(path)
    raw = _read_bytes(path, shown)
    for bom, name in ((codecs.BOM_UTF32_LE, "UTF-32"), (codecs.BOM_UTF32_BE, "UTF-32"),
                      (codecs.BOM_UTF16_LE, "UTF-16"), (codecs.BOM_UTF16_BE, "UTF-16")):
        if raw.startswith(bom):
            raise ConfigError("", f"{shown}: is {name} text; expected UTF-8 (save the file as UTF-8)")
    if b"\x00" in raw:
        raise ConfigError("", f"{shown}: contains NUL bytes (a binary file?); expected UTF-8 TOML text")
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as err:
        line = raw.count(b"\n", 0, err.start) + 1
        raise ConfigError("", f"{shown}: not UTF-8 text (byte 0x{raw[err.start]:02x} on line {line}); expected "
                          f"UTF-8 TOML (save the file as UTF-8)") from None
    try:
        return tomllib.loads(text.removeprefix("\ufeff"))
    except tomllib.TOMLDecodeError as err:
        raise ConfigError("", f"{shown}: not valid TOML ({one_line(err) or type(err).__name__})") from None
    except RecursionError:
        raise ConfigError("", f"{shown}: not valid TOML (arrays or tables nested too deeply)") from None


def _read_bytes(path: Path, shown: str) -> bytes:
    """The bytes of ``path``, after checking its size against the ``file_bytes`` limit (one-line errors)."""
    try:
        size = path.stat().st_size
        try:
            check("file_bytes", size, shown)
        except ConfigError as err:
            raise ConfigError("", str(err)) from None
        return path.read_bytes()
    except OSError as err:
        what = os.strerror(err.errno).lower() if err.errno else type(err).__name__
        raise ConfigError("", f"{shown}: cannot read it ({what})") from None
