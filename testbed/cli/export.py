"""``testbed export RUN --format FORMAT [--out FILE]``: a finished run in another form (testbed/export/)."""
from __future__ import annotations

import argparse


def add_export_parser(sub) -> None:
    from ..export import FORMATS

    e = sub.add_parser("export", help="write a finished run in another form: " + "; ".join(
        f"{name}: {f.doc}" for name, f in FORMATS.items()))
    e.add_argument("run", help="a run folder (testbed run ... --out RUN)")
    e.add_argument("--format", required=True, metavar="FORMAT",
                   help=f"one of: {', '.join(sorted(FORMATS))}")
    e.add_argument("--out", help="file (folder, for kitti) to write (default: the format's file or folder in the run folder, e.g. replay.html, kitti/)")
    e.set_defaults(func=cmd_export)


def cmd_export(args: argparse.Namespace) -> int:
    from ..export import export_run

    path = export_run(args.run, args.format, args.out)
    size = sum(p.stat().st_size for p in path.rglob("*") if p.is_file()) if path.is_dir() else path.stat().st_size
    print(f"wrote {path} ({size / 1e6:.1f} MB)")
    if args.format == "html":
        print(f"open it in any browser (no GPU, no network needed): file://{path.resolve()}; "
              "#t=SECONDS or #event=N opens at a time or an event")
    return 0
