"""``testbed campaign run|resume|report``: Monte Carlo campaigns from the command line.

``add_campaign_parser(subparsers)`` adds the ``campaign`` command to ``testbed``'s argparse;
``python -m roadtrack.testbed.cli.campaign run|resume|report ...`` runs the same sub-commands stand-alone.

Exit codes: 0 done (runs that failed inside the scenario or tracker are recorded, not fatal);
1 the engine failed (a worker died, the scheduler is unreachable, the disk is full): finished runs are
kept, resume; 2 bad input (malformed campaign file or --scheduler address, not a campaign directory or a
damaged one, a folder in use by another campaign process): nothing written; 130 Ctrl-C, 143 SIGTERM, 129
SIGHUP (finished runs are kept, resume). The sub-command
functions raise ConfigError / RunError / OSError and leave the one-line message and the exit code to
:func:`testbed.common.errors.guarded` (``testbed``'s and this module's :func:`main`).

Only the standard library is imported at module level: spawned workers re-import this module.
"""
from __future__ import annotations

import argparse
import signal
import sys
from pathlib import Path


POOL_MAX = 256
"""Most worker processes or threads per worker an option may ask for (a pool of 10^6 would exhaust the
machine before the first run; 256 is well above the cores of any one machine these runs use)."""


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected an integer >= 0, got {value}")
    if value > POOL_MAX:
        raise argparse.ArgumentTypeError(f"expected at most {POOL_MAX}, got {value}")
    return value


def _at_least_one(text: str) -> int:
    value = _positive_int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {value}")
    return value


def _engine_args(p: argparse.ArgumentParser) -> None:
    g = p.add_mutually_exclusive_group()
    g.add_argument("--workers", type=_positive_int, metavar="N",
                   help="local worker processes (default: the usable cores; 0 = in this process, for debugging)")
    g.add_argument("--scheduler", metavar="ADDR", help="run on a Dask distributed scheduler, e.g. tcp://host:8786")
    g.add_argument("--dask-local", type=_positive_int, metavar="N",
                   help="start a Dask LocalCluster of N single-threaded worker processes (for testing)")
    p.add_argument("--threads", type=_at_least_one, metavar="N",
                   help="threads (OpenMP, and as many pinned cores) per local worker (default: cores // workers; "
                   "results do not depend on it)")
    p.add_argument("--no-sensing-cache", action="store_true",
                   help="sense the traffic anew for every run (default: each traffic is sensed once into the "
                        "campaign folder's sensing/ and every tracker runs on it; results are identical)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def _engine(args: argparse.Namespace):
    """The engine options of the command line; a malformed ``--scheduler`` is a ConfigError."""
    from ..config import ConfigError
    from ..campaign.engine import EngineOptions, check_scheduler_address

    if args.dask_local == 0:
        raise ConfigError("--dask-local", "0 is not allowed; must be >= 1")
    if args.scheduler is not None:
        check_scheduler_address(args.scheduler)
    return EngineOptions(workers=args.workers, scheduler=args.scheduler, dask_local=args.dask_local,
                         threads=args.threads, sensing_cache=not args.no_sensing_cache)


def _reach(engine) -> None:
    """A RunError now, before anything is written, if ``--scheduler`` does not answer."""
    if engine.scheduler is not None:
        from ..campaign.engine import check_scheduler

        check_scheduler(engine.scheduler)


def _execute(campaign, out: Path, engine, args: argparse.Namespace, retry_errors: bool = False) -> int:
    from ..common.errors import RunError, describe_os_error, interruption, signal_exit_code
    from ..campaign.engine import run_campaign

    try:
        outcome = run_campaign(campaign, out, engine, quiet=args.quiet, retry_errors=retry_errors)
    except OSError as err:  # e.g. a full disk: the finished runs are kept
        raise RunError(f"{describe_os_error(err)}; the finished runs are kept: resume with: testbed campaign "
                       f"resume {out}") from None
    done = outcome.before + outcome.ran
    failed = f" ({outcome.failed} failed: see the error column)" if outcome.failed else ""
    if outcome.interrupted:  # Ctrl-C, SIGTERM or SIGHUP: one line, exit 128 + the signal
        signum = outcome.signum or signal.SIGINT
        print(f"{interruption(signum)}: {done} of {outcome.total} runs finished{failed} and kept in {out}/; "
              f"resume with: testbed campaign resume {out}", file=sys.stderr)
        return signal_exit_code(signum)
    if outcome.broken:
        print(f"error: {outcome.broken}; {done} of {outcome.total} runs finished and kept in {out}/; "
              f"resume with: testbed campaign resume {out}", file=sys.stderr)
        return 1
    print(f"{campaign.name}: {done} runs{failed}, {outcome.ran} run now; results: {out / 'results.parquet'}")
    print(f"summary: testbed campaign report {out}")
    return 0


def _cmd_run(args: argparse.Namespace) -> int:
    """``campaign run``: errors are raised (ConfigError -> exit 2, RunError / OSError -> 1) for
    :func:`testbed.common.errors.guarded`; nothing is written before the campaign and the engine check out."""
    from ..campaign import store
    from ..campaign.spec import load_campaign

    campaign = load_campaign(args.file)
    if args.out is not None and not args.out.strip():  # not silently the default folder
        from ..config import ConfigError

        raise ConfigError("--out", "is empty; give a folder path")
    out = Path(args.out) if args.out else Path("runs") / "campaigns" / campaign.name
    engine = _engine(args)
    _reach(engine)
    store.create(out, campaign.source, campaign)
    return _execute(campaign, out, engine, args)


def _cmd_resume(args: argparse.Namespace) -> int:
    from ..campaign import store

    campaign = store.open_campaign(args.dir)
    engine = _engine(args)
    _reach(engine)
    return _execute(campaign, Path(args.dir), engine, args, retry_errors=args.retry_errors)


def _cmd_report(args: argparse.Namespace) -> int:
    """``campaign report``: reads only finished runs, so it may run while the campaign runs."""
    from ..common.errors import RunError
    from ..campaign import store
    from ..campaign.report import write_report

    campaign = store.open_campaign(args.dir)
    rep = write_report(args.dir, campaign)
    if rep.n_runs == 0:
        raise RunError(f"{args.dir}: no finished run yet (run or resume the campaign first)")
    print(f"{rep.n_runs} runs ({rep.n_failed} failed): {len(rep.tables)} tables, {len(rep.plots)} plots")
    print(f"wrote {rep.path}")
    return 0


def _add_subcommands(sub, debug: bool = False) -> None:
    """run, resume and report; with ``debug`` each also takes ``--debug`` (after the sub-command)."""
    r = sub.add_parser("run", help="run a campaign file into a new results directory")
    r.add_argument("file", help="campaign file, or the name of a shipped one (campaigns/*.toml)")
    r.add_argument("--out", metavar="DIR", help="results directory (default runs/campaigns/<name>); must not "
                   "hold a campaign yet")
    _engine_args(r)
    r.set_defaults(func=_cmd_run)
    s = sub.add_parser("resume", help="finish an interrupted campaign: run only the runs DIR does not hold")
    s.add_argument("dir", metavar="DIR", help="results directory of `testbed campaign run`")
    _engine_args(s)
    s.add_argument("--retry-errors", action="store_true", help="also re-run the runs that failed")
    s.set_defaults(func=_cmd_resume)
    p = sub.add_parser("report", help="mean, sd and 95%% CI tables and plots of a campaign: DIR/report.md")
    p.add_argument("dir", metavar="DIR", help="results directory")
    p.set_defaults(func=_cmd_report)
    if debug:
        for parser in (r, s, p):
            parser.add_argument("--debug", action="store_true", default=argparse.SUPPRESS,
                                help="show the traceback of an error")


def add_campaign_parser(subparsers) -> argparse.ArgumentParser:
    """Add ``campaign run|resume|report`` to an argparse sub-parser collection (``testbed``'s)."""
    c = subparsers.add_parser("campaign", help="Monte Carlo campaigns: scenarios x trackers x seeds x grids",
                              description="Monte Carlo campaigns (see docs/campaigns.md).")
    sub = c.add_subparsers(dest="campaign_command", required=True)
    _add_subcommands(sub)
    return c


def main(argv: list[str] | None = None) -> int:
    """``python -m roadtrack.testbed.cli.campaign [--debug] run|resume|report ...`` = ``testbed campaign ...``: every
    error one line on stderr (with ``--debug`` also its traceback) and exit code 1 or 2."""
    from ..common.errors import guarded

    p = argparse.ArgumentParser(prog="python -m roadtrack.testbed.cli.campaign",
                                description="Monte Carlo campaigns (see docs/campaigns.md).")
    p.add_argument("--debug", action="store_true", help="show the traceback of an error")
    _add_subcommands(p.add_subparsers(dest="campaign_command", required=True), debug=True)
    args = p.parse_args(argv)
    return guarded(args.func, args, args.debug)


if __name__ == "__main__":
    sys.exit(main())
