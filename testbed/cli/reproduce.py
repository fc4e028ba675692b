"""``testbed reproduce NAME [--quick] [--seed N] [--out DIR] [--quiet]``: a paper's figures and numbers."""
from __future__ import annotations

import argparse
import os
from pathlib import Path

from ..config import ConfigError
from ..config.limits import SEED_MAX, check_seed
from ..reproduce import REPRODUCTIONS, entry


def _cmd_reproduce(args: argparse.Namespace) -> int:
    if args.name == "list":
        for name, (_, text) in REPRODUCTIONS.items():
            print(f"{name:<10} {text}")
        return 0
    try:
        run = entry(args.name)
    except KeyError as err:
        raise ConfigError("reproduce", err.args[0]) from None
    seed = check_seed(args.seed, "--seed")  # every option is checked before the folder is made
    out = _out_folder(args)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise ConfigError("--out", f"cannot create {out} ({os.strerror(err.errno).lower() if err.errno else err}); "
                          "choose another --out") from None
    summary = run(out, quick=args.quick, seed=seed, progress=not args.quiet)
    print(f"wrote {summary} and its figures")
    return 0


def _out_folder(args: argparse.Namespace) -> Path:
    """The report folder of ``--out`` (default runs/reproduce/NAME[-quick]): ConfigError if it, or a folder
    above it, is a file."""
    if args.out is not None and not args.out.strip():
        raise ConfigError("--out", "is empty; give a folder path")
    out = Path(args.out) if args.out else Path("runs") / "reproduce" / (args.name + ("-quick" if args.quick else ""))
    above = next((p for p in (out, *out.parents) if p.exists() or p.is_symlink()), None)
    if above is not None and not above.is_dir():
        what = f"{out} is a file" if above == out else f"cannot create {out}: {above} is a file"
        raise ConfigError("--out", f"{what}, not a folder; choose another --out")
    return out


def add_reproduce_parser(subparsers) -> argparse.ArgumentParser:
    """Add ``reproduce`` to ``testbed``'s sub-commands."""
    names = ", ".join(REPRODUCTIONS)
    r = subparsers.add_parser("reproduce", help=f"regenerate a paper's figures and numbers ({names}; `list`)",
                              description="Writes PNG figures and summary.md (the paper's numbers beside ours).")
    r.add_argument("name", help=f"one of {names}, or `list`")
    r.add_argument("--quick", action="store_true", help="reduced run (fewer Monte Carlo runs and steps)")
    r.add_argument("--seed", type=int, default=0, help=f"seed in 0..{SEED_MAX} (default 0)")
    r.add_argument("--out", help="report folder (default runs/reproduce/NAME)")
    r.add_argument("--quiet", action="store_true", help="no progress bars")
    r.set_defaults(func=_cmd_reproduce)
    return r
