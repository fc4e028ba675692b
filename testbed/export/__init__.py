"""Export: a finished run folder written in another form, one module per format.

    FORMATS                                    {name: Format}: the registry (``testbed export RUN --format NAME``)
    export_run(folder, fmt, out=None) -> Path  write run ``folder`` as ``fmt`` (default file: in the folder)

Adding a format (kitti, mot, csv, ...) = one module with a ``write(run, path) -> Path`` function taking a
testbed.pipeline.runfolder.RunData, and one line in :data:`FORMATS` naming it (imported only when a run is
exported). A format that writes a folder (kitti, csv, mot) says
so with ``folder=True``: its ``path`` is then a folder (created if missing).
"""
from __future__ import annotations

import importlib
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from ..config import ConfigError
from ..common.safe_io import refuse_link


@dataclass(frozen=True)
class Format:
    """module: the format's module in this package, whose ``write(run, path) -> Path`` writes it (imported when a
    run is exported, so that the CLI starts without the formats' dependencies); default_name: the file (or folder)
    written in the run folder without ``out``; doc: one line; folder: the format writes a folder, not a file."""

    module: str
    default_name: str
    doc: str
    folder: bool = False

    @property
    def write(self) -> Callable[..., Path]:
        """The module's ``write(run: testbed.pipeline.runfolder.RunData, path: Path) -> Path``."""
        return importlib.import_module(f"{__name__}.{self.module}").write


FORMATS: dict[str, Format] = {
    "html": Format("html", "replay.html", "a light top-down replay with a time slider, one self-contained "
                                              "file that opens in any browser without a GPU or a network"),
    "kitti": Format("kitti", "kitti", "a KITTI-tracking sequence (velodyne scans, labels, calib, oxts; "
                                          "docs/formats.md) for the 3-D MOT tools; `testbed replay` reads it",
                    folder=True),
    "csv": Format("csv_tables", "csv", "the truth, detections (with their covariance R), tracks and events as "
                                           "CSV files for a program in any language (docs/formats.md)", folder=True),
    "mot": Format("mot", "mot", "a MOTChallenge sequence (gt, det, the tracks; bird's-eye boxes in metres, "
                                    "docs/formats.md) that TrackEval's MotChallenge2DBox reads", folder=True),
}


def export_run(folder: str | Path, fmt: str, out: str | Path | None = None) -> Path:
    """Write the run in ``folder`` as ``fmt`` into ``out`` (default: the format's file or folder in the run folder).
    ConfigError (one line) for an unknown format, a folder that is not a run, or an ``out`` of the wrong kind (a folder
    for a file format, a file for a folder format, a symbolic link)."""
    if fmt not in FORMATS:
        raise ConfigError("--format", f"unknown format {fmt!r}; allowed: {', '.join(sorted(FORMATS))}")
    from ..pipeline.runfolder import read_run

    f = FORMATS[fmt]
    run = read_run(folder)
    path = Path(out) if out is not None else Path(folder) / f.default_name
    if f.folder:
        refuse_link(path, "--out")
        if path.exists() and not path.is_dir():
            raise ConfigError("--out", f"{path} is a file; the {fmt} format writes a folder")
    elif path.is_dir():
        raise ConfigError("--out", f"{path} is a folder; give a file name")
    return f.write(run, path)
