"""``testbed reproduce NAME [--quick] [--seed N] [--out DIR] [--quiet]``: a paper's figures and numbers."""
from __future__ import annotations

import argparse
from pathlib import Path

from . import REPRODUCTIONS, entry


def _cmd_reproduce(args: argparse.Namespace) -> int:
    if args.name == "list":
        for name, (_, text) in REPRODUCTIONS.items():
            print(f"{name:<10} {text}")
        return 0
    from ..config import ConfigError

    try:
        run = entry(args.name)
    except KeyError as err:
        raise ConfigError("reproduce", err.args[0]) from None
    out = Path(args.out) if args.out else Path("runs") / "reproduce" / (args.name + ("-quick" if args.quick else ""))
    if out.exists() and not out.is_dir():
        raise ConfigError("--out", f"{out} is a file, not a folder")
    out.mkdir(parents=True, exist_ok=True)
    summary = run(out, quick=args.quick, seed=args.seed, progress=not args.quiet)
    print(f"wrote {summary} and its figures")
    return 0


def add_reproduce_parser(subparsers) -> argparse.ArgumentParser:
    """Add ``reproduce`` to ``testbed``'s sub-commands."""
    names = ", ".join(REPRODUCTIONS)
    r = subparsers.add_parser("reproduce", help=f"regenerate a paper's figures and numbers ({names}; `list`)",
                              description="Writes PNG figures and summary.md (the paper's numbers beside ours).")
    r.add_argument("name", help=f"one of {names}, or `list`")
    r.add_argument("--quick", action="store_true", help="reduced run (fewer Monte Carlo runs and steps)")
    r.add_argument("--seed", type=int, default=0, help="seed (default 0)")
    r.add_argument("--out", help="report folder (default runs/reproduce/NAME)")
    r.add_argument("--quiet", action="store_true", help="no progress bars")
    r.set_defaults(func=_cmd_reproduce)
    return r
