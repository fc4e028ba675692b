"""Export: a finished run folder written in another form, one module per format.

    FORMATS                                    {name: Format}: the registry (``testbed export RUN --format NAME``)
    export_run(folder, fmt, out=None) -> Path  write run ``folder`` as ``fmt`` (default file: in the folder)

Adding a format (kitti, mot, csv, ...) = one module with a ``write(run, path) -> Path`` function taking a
testbed.pipeline.runfolder.RunData, and one line in :data:`FORMATS`. A format that writes a folder (kitti) says
so with ``folder=True``: its ``path`` is then a folder (created if missing).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from ..config import ConfigError
from ..pipeline.runfolder import RunData, read_run
from . import html, kitti


@dataclass(frozen=True)
class Format:
    """write(run, path) -> Path; default_name: the file (or folder) written in the run folder without ``out``;
    doc: one line; folder: the format writes a folder, not a file."""

    write: Callable[[RunData, Path], Path]
    default_name: str
    doc: str
    folder: bool = False


FORMATS: dict[str, Format] = {
    "html": Format(html.write, "replay.html", "a light top-down replay with a time slider, one self-contained "
                                              "file that opens in any browser without a GPU or a network"),
    "kitti": Format(kitti.write, "kitti", "a KITTI-tracking sequence (velodyne scans, labels, calib, oxts; "
                                          "docs/formats.md) for the 3-D MOT tools; `testbed replay` reads it",
                    folder=True),
}


def export_run(folder: str | Path, fmt: str, out: str | Path | None = None) -> Path:
    """Write the run in ``folder`` as ``fmt`` into ``out`` (default: the format's file in the folder). ConfigError
    (one line) for an unknown format or a folder that is not a run."""
    if fmt not in FORMATS:
        raise ConfigError("--format", f"unknown format {fmt!r}; allowed: {', '.join(sorted(FORMATS))}")
    f = FORMATS[fmt]
    run = read_run(folder)
    path = Path(out) if out is not None else Path(folder) / f.default_name
    if f.folder:
        kitti.check_target(path)
    elif path.is_dir():
        raise ConfigError("--out", f"{path} is a folder; give a file name")
    return f.write(run, path)
