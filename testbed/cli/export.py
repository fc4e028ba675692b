"""``testbed export RUN --format FORMAT [--out FILE]``: a finished run in another form (testbed/export/)."""
from __future__ import annotations

import argparse
import os
import stat
from pathlib import Path


def add_export_parser(sub) -> None:
    from ..export import FORMATS

    e = sub.add_parser("export", help="write a finished run in another form: " + "; ".join(
        f"{name}: {f.doc}" for name, f in FORMATS.items()))
    e.add_argument("run", help="a run folder (testbed run ... --out RUN)")
    e.add_argument("--format", required=True, metavar="FORMAT",
                   help=f"one of: {', '.join(sorted(FORMATS))}")
    e.add_argument("--out", help="file, or folder for kitti, csv and mot, to write (default: the format's file or "
                                 "folder in the run folder, e.g. replay.html, kitti/, csv/)")
    e.set_defaults(func=cmd_export)


def cmd_export(args: argparse.Namespace) -> int:
    from ..export import export_run

    path = export_run(args.run, args.format, args.out)
    size = _size(path)
    print(f"wrote {path} ({size / 1e6:.1f} MB)")
    if args.format == "html":
        print(f"open it in any browser (no GPU, no network needed): file://{path.resolve()}; "
              "#t=SECONDS or #event=N opens at a time or an event")
    elif args.format == "csv":
        print(f"a tracker in any language reads {path / 'detections.csv'}; `testbed score {args.run} --tracks FILE` "
              "scores its tracks (examples/nn_tracker.awk; columns: docs/formats.md)")
    elif args.format == "mot":
        print(f"TrackEval's MotChallenge2DBox reads it: GT_FOLDER {path / 'gt'}, TRACKERS_FOLDER {path / 'trackers'}, "
              "BENCHMARK ROADTRACK, SPLIT_TO_EVAL all, SKIP_SPLIT_FOL True (boxes, frames, classes: docs/formats.md)")
    return 0


def _size(path: Path) -> int:
    """Bytes of the file ``path``, or of the regular files in the folder ``path`` (symbolic links not followed)."""
    if not path.is_dir():
        return path.stat().st_size
    total = 0
    for root, _dirs, files in os.walk(path):  # os.walk does not descend into links to folders
        for name in files:
            st = os.lstat(os.path.join(root, name))
            total += st.st_size if stat.S_ISREG(st.st_mode) else 0
    return total
