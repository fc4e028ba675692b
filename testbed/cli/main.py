"""``testbed`` command line: run scenarios, view recordings, check files, list scenarios and trackers, warm up.

Exit codes (every command): 0 success; 1 run-time failure (what was finished is kept); 2 bad input
(malformed file or option, unusable output folder), nothing run; 130 Ctrl-C, 143 SIGTERM, 129 SIGHUP (what
was finished is kept). An error is ONE line on stderr (``error: ...``); ``--debug`` (before or after the
command) adds its traceback.
"""
from __future__ import annotations

import argparse
import contextlib
import os
import sys
import traceback
import warnings
from pathlib import Path

from ..common.threads import one_thread_per_process
from ..config import ConfigError, parse_sets
from .check import cmd_check
from ..common.errors import (describe_os_error, exit_code, guarded, interruption, interruption_behind,
                             interruption_cause, one_line, signum_of)
from ..recording.view import WEB_VIEWER_PORT, at_arg, cmd_view, event_arg, port_arg


class _Parser(argparse.ArgumentParser):
    """argparse with one-line usage errors (exit 2)."""

    def error(self, message: str):
        self.exit(2, f"error: {self.prog}: {message} (see `{self.prog} --help`)\n")


def _cmd_run(args: argparse.Namespace) -> int:
    from ..pipeline.outdir import RUN_FILES, Staging
    from ..world import load_scenario

    from ..tracking import is_factory_spec, load_tracker

    overrides = parse_sets(args.set or [])
    user = is_factory_spec(args.tracker)  # --tracker my_module:MyTracker or a named one (stonesoup-jpda-kf)
    if args.tracker is not None and not user:
        check_combination(args.tracker)
        overrides["tracker.name"] = args.tracker  # "" is refused by the loader, not silently ignored
    if args.seed is not None:
        overrides["seed"] = args.seed
    if args.record is not None:
        overrides["record.level"] = args.record  # checked by the loader: an unknown level names the allowed ones
    scn = load_scenario(args.scenario, overrides)
    policy = _policy(args.policy, scn) if args.policy is not None else None
    tracker = load_tracker(args.tracker) if user else None  # imported once, before any simulation
    out = args.out if args.out is not None else str(Path("runs") / scn.name)  # the loader checked the name
    stage = Staging(out, RUN_FILES)  # refused up front (exit 2), before any simulation
    try:
        res = _run_with_progress(scn, stage.tmp, args, policy, tracker)
        if not args.no_plot:
            _plot_run(stage.tmp, args)  # a drawing error is a warning; Ctrl-C here keeps the tables as above
    except (Exception, KeyboardInterrupt) as err:  # noqa: BLE001 - kept, marked INCOMPLETE, one line
        return failed(err, stage, args.debug)
    commit(stage)
    print_run(res, args, stage.shown)
    return 0


def _cmd_replay(args: argparse.Namespace) -> int:
    """``testbed replay``: the sequence run like a live run (testbed.pipeline.replay), its folder written like a run's."""
    from tqdm import tqdm

    from ..pipeline.outdir import RUN_FILES, Staging
    from ..pipeline.replay import replay_scenario, KittiSource
    from ..pipeline.run import run_scenario
    from ..sensing.kitti import open_sequence
    from ..tracking import is_factory_spec, load_tracker

    overrides = parse_sets(args.set or [])
    user = is_factory_spec(args.tracker)
    if args.tracker is not None and not user:
        check_combination(args.tracker)
        overrides["tracker.name"] = args.tracker
    seq = open_sequence(args.sequence_dir, args.sequence)
    given = None
    if args.scenario is not None:
        from ..world import load_scenario

        given = load_scenario(args.scenario, overrides)
    scn, carried = replay_scenario(seq, given, overrides)
    if args.road and not (carried or given is not None):
        raise ConfigError("--road", "no scenario came with the sequence; give one with --scenario")
    tracker = load_tracker(args.tracker) if user else None
    label = args.tracker if args.tracker is not None else scn.tracker.name
    out = args.out if args.out is not None else str(Path("runs") / f"replay-{seq.name}")
    stage = Staging(out, RUN_FILES)
    road = carried if args.road is None else args.road
    try:
        with tqdm(total=scn.n_frames, desc=f"replay {seq.name} [{label}]", unit="frame",
                  disable=args.quiet or None, leave=False) as bar:
            res = run_scenario(scn, out_dir=stage.tmp, record=not args.no_record, tracker=tracker, label=label,
                               on_frame=frame_progress(bar), source=KittiSource(seq, scn, road))
    except (Exception, KeyboardInterrupt) as err:  # noqa: BLE001 - kept, marked INCOMPLETE, one line
        return failed(err, stage, args.debug)
    commit(stage)
    print_run(res, args, stage.shown)
    return 0


def _plot_run(folder: Path, args: argparse.Namespace) -> None:
    """timeline.png of a finished run; a failure to draw it is one warning line (the run's results stand) and
    args.no_plot is set so the summary does not list it."""
    from ..pipeline.plots import write_run_plots

    try:
        write_run_plots(folder)
    except Exception as err:  # noqa: BLE001 - a figure never costs the run its results
        print(f"warning: timeline.png not drawn: {type(err).__name__}: {one_line(err)}", file=sys.stderr)
        args.no_plot = True


def check_combination(name: str) -> None:
    """``--tracker NAME`` that is not a named tracker must be a built-in combination: one line listing both."""
    from roadtrack.trackers import parse_tracker_name

    from ..tracking.registry import unknown_tracker

    try:
        parse_tracker_name(name)
    except ValueError:
        raise ConfigError("--tracker", unknown_tracker(name)) from None


def _policy(text: str, scn):
    """The ego policy named by ``--policy`` (the user typed it: code never comes from a scenario file)."""
    from ..world.envsource import load_policy

    if scn.env is None:
        raise ConfigError("--policy", f"scenario {scn.name} has no [env] table; --policy drives the ego of a "
                                      "highway-env environment (e.g. scenarios/merge.toml)")
    return load_policy(text)


def _run_with_progress(scn, out: Path, args: argparse.Namespace, policy=None, tracker=None):
    from tqdm import tqdm

    from ..pipeline.run import run_scenario

    label = args.tracker if tracker is not None else scn.tracker.name
    with tqdm(total=scn.n_frames, desc=f"{scn.name} [{label}]", unit="frame",
              disable=args.quiet or None, leave=False) as bar:
        return run_scenario(scn, out_dir=out, record=not args.no_record, on_frame=frame_progress(bar),
                            policy=policy, tracker=tracker, label=label)


def frame_progress(bar):
    """``on_frame(i, n)`` for a run's tqdm ``bar`` whose clock starts when the first frame is done: the set-up
    (traffic, recorder, compiled kernels' warm-up) and the first frame are not counted in the rate, which made
    the first estimate of the time left 40-60 times too long (issue 34.4)."""

    def on_frame(i: int, n: int) -> None:
        if i == 1:
            bar.reset(total=n)
            bar.n = bar.last_print_n = bar.initial = 1  # the rate counts frames from the second on
            bar.refresh()
        else:
            bar.update(1)

    return on_frame


def failed(err: BaseException, stage, debug: bool) -> int:
    """A command that wrote into ``stage`` failed or was interrupted: keep what it wrote (marked INCOMPLETE)
    in the output folder, print one line saying what happened and where it is, return the exit code."""
    err = interruption_behind(err)
    interrupted = isinstance(err, KeyboardInterrupt)
    written = stage.written()
    head = interruption_cause(signum_of(err)) if interrupted else stage.shown_text(_headline(err))
    notes = [stage.shown_text(n) for n in getattr(err, "__notes__", [])]
    if written:
        where = stage.abandon("; ".join([head, *notes]))
        shown = stage.shown if where == stage.path else str(where)
        tables = any(name.endswith(".parquet") for name in written)
        kept = f"the tables of the frames before it are in {shown}/" if tables else \
            f"{', '.join(written)} kept in {shown}/"
        kept += ", marked INCOMPLETE"
    else:
        stage.discard()
        kept = f"nothing was written ({stage.shown} is unchanged)"
    if debug:
        traceback.print_exception(err, file=sys.stderr)
    detail = "; ".join([*notes, kept])
    print(f"{interruption(signum_of(err))}: {detail}" if interrupted else f"error: {head} ({detail})",
          file=sys.stderr)
    return exit_code(err)


def commit(stage) -> None:
    """Move the finished output into place; if that fails, say where it is (exit 1)."""
    from ..common.errors import RunError

    try:
        stage.commit()
    except OSError as err:
        raise RunError(f"{stage.shown_text(describe_os_error(err))}; the finished output is in {stage.tmp}/") from err


def _headline(err: BaseException) -> str:
    """What went wrong, one line: an OSError as ``path: what``, a tracker's error with its type."""
    from ..common.errors import RunError

    if isinstance(err, OSError):
        return describe_os_error(err)
    if isinstance(err, ConfigError | RunError):
        return one_line(err)
    return f"{type(err).__name__}: {one_line(err)}"


def _print_scores(label: str, scores, m: dict) -> None:
    """The score table (thesis form left of |, ours right) and the MOT metrics lines."""
    from ..scoring.rates import format_table

    print(format_table({label: scores}))
    for label, sfx in (("visible truth", ""), ("all truth    ", "_all")):
        print(f"{label}: HOTA {m['hota' + sfx]:.3f}  MOTA {m['mota' + sfx]:.3f}  MOTP {m['motp' + sfx]:.3f}  "
              f"IDF1 {m['idf1' + sfx]:.3f}  ID switches {m['id_switches' + sfx]:.0f}  GOSPA {m['gospa' + sfx]:.2f} m "
              f"(per frame: missed {m['gospa_missed' + sfx]:.2f}, false {m['gospa_false' + sfx]:.2f}, "
              f"localisation {m['gospa_localisation' + sfx]:.2f} m^2)")
    if "bev_hota" in m:  # box tracking (tracker.box)
        print(f"box overlap  : HOTA {m['bev_hota']:.3f}  MOTA {m['bev_mota']:.3f}  MOTP {m['bev_motp']:.3f}  "
              f"IDF1 {m['bev_idf1']:.3f}  ID switches {m['bev_id_switches']:.0f}  mean IoU {m['bev_mean_iou']:.3f} "
              "(bird's-eye-view IoU as the similarity, visible truth; a match needs IoU >= 0.5)")


def print_run(res, args: argparse.Namespace, out: str) -> None:
    from ..pipeline.run import further_tables
    from ..scoring.events import format_events

    _print_scores(f"{res.scenario.name}/{res.tracker}", res.scores, res.metrics)
    if res.events is not None:
        print("\n" + format_events(res.events))
    per_frame = sum(res.timings_ms.values())
    print(f"\n{res.n_frames} frames, {per_frame:.1f} ms/frame "
          f"({', '.join(f'{k} {v:.1f}' for k, v in res.timings_ms.items())}), "
          f"{res.fallbacks} association fallback{'' if res.fallbacks == 1 else 's'}"
          + (f", {res.stitched} stitched track{'' if res.stitched == 1 else 's'} (tracker.stitch_s: the scores count "
             f"each as the track it continues)" if res.scenario.tracker.stitch_s > 0 else ""))
    written = ["scores.json", "truth.parquet", "detections.parquet", "tracks.parquet", "diagnostics.parquet",
               "events.parquet"]
    written[3:3] = [f"detections-{n}.parquet" for n in further_tables(res.scenario)]  # the further sensors' tables
    if not args.no_record:
        written.insert(0, "run.rrd")
    if not args.no_plot:
        written.append("timeline.png")
    print(f"wrote {', '.join(written)} to {out}/")
    if not args.no_record:
        from ..recording.levels import lidar_step  # numpy: not at import (testbed/common/threads.py)

        rec = res.scenario.record
        step = lidar_step(rec.lidar_every, rec.max_lidar_frames, res.scenario.n_frames)
        if step > rec.lidar_every:
            print(f"run.rrd holds the point cloud of every {_ordinal(step)} frame: a {res.scenario.n_frames}-frame "
                  f"run, record.max_lidar_frames = {rec.max_lidar_frames} (0: every frame)")
        first = " (--event N: at event N)" if res.events is not None and len(res.events) else ""
        print(f"view it: testbed view {out}{first}; without a GPU: testbed export {out} --format html")


def _ordinal(n: int) -> str:
    return f"{n}{'th' if 10 <= n % 100 <= 20 else {1: 'st', 2: 'nd', 3: 'rd'}.get(n % 10, 'th')}"


def _cmd_score(args: argparse.Namespace) -> int:
    """Score a run's tracks, or another program's tracks table (parquet or CSV), against the run's truth."""
    from ..scoring.evaluate import score
    from ..common.jsonio import json_text
    from ..pipeline.runfolder import read_run
    from ..scenario.spec import ScoringSpec

    run = read_run(args.run)
    if args.tracks is None:
        tracks, label = run.tracks, f"{run.scores.get('scenario', Path(args.run).name)}/{run.scores.get('tracker', '?')}"
    else:
        tracks, label = _read_tracks(args.tracks), f"{Path(args.tracks).name}"
    scoring = run.scenario.scoring if run.scenario is not None else ScoringSpec()
    ev = score(run.truth, tracks, scoring, run.n_frames)
    if args.json:
        print(json_text(dict(run=str(args.run), tracks=args.tracks, scores=ev.scores.to_dict(), mot_metrics=ev.metrics),
                        indent=2, default=float))
    else:
        from ..scoring.events import format_events, run_events

        _print_scores(label, ev.scores, ev.metrics)
        dt = run.scenario.dt if run.scenario is not None else 0.1
        print("\n" + format_events(run_events(run.truth, tracks, scoring, dt)))
    return 0


def _read_tracks(path: str):
    """A tracks table from a .parquet or .csv file (schema: testbed/scoring/evaluate.py, docs/api.md)."""
    import pandas as pd

    p = Path(path)
    if not p.is_file():
        raise ConfigError("--tracks", f"{path}: no such file")
    try:
        if p.suffix.lower() == ".csv":
            return pd.read_csv(p)
        if p.suffix.lower() in (".parquet", ".pq"):
            return pd.read_parquet(p)
    except Exception as err:  # noqa: BLE001 - a file we cannot parse is the option's error
        raise ConfigError("--tracks", f"{path}: cannot be read ({type(err).__name__}: {one_line(err)})") from None
    raise ConfigError("--tracks", f"{path}: expected a .csv or .parquet file")


def _cmd_perception(args: argparse.Namespace) -> int:
    from ..pipeline.outdir import REPORT_FILES, Staging
    from ..perception.report import check_settings_path, write_settings
    from ..scenario.spec import apply_overrides, read_toml
    from ..world import parse_scenario

    base = apply_overrides(read_toml(args.scenario), parse_sets(args.set or []))  # what --write-settings keeps
    run = {"seed": args.seed, "duration_s": args.duration}
    data = apply_overrides(base, {k: v for k, v in run.items() if v is not None})
    scn = parse_scenario(data)
    # a folder, or a file this command did not write, is refused before the characterisation
    settings_path = check_settings_path(args.write_settings) if args.write_settings is not None else None
    out = args.out if args.out is not None else str(Path("runs") / "perception" / scn.name)
    stage = Staging(out, REPORT_FILES)
    try:
        ch, abl, settings, md = _characterise(scn, data, stage.tmp, args)
    except (Exception, KeyboardInterrupt) as err:  # noqa: BLE001 - one line
        return failed(err, stage, args.debug)
    commit(stage)
    s = ch.summary()
    print(f"ground precision {100 * s['ground_precision']:.2f} %, recall {100 * s['ground_recall']:.2f} %; "
          f"P_D in range {s['pd_in_range']:.3f} (visible {s['pd_visible']:.3f}, occluded {s['pd_occluded']:.3f}); "
          f"split {s['split_rate']:.4f}, merge {s['merge_rate']:.4f}; clutter {s['clutter_per_frame']:.2f}/frame "
          f"({s['clutter_per_m2_road']:.2e}/m^2 of road); centre RMSE box {s['centre_rmse_box_m']:.2f} m, "
          f"centroid {s['centre_rmse_centroid_m']:.2f} m")
    if abl:
        print("false confirmed tracks: " + ", ".join(f"{k} {v['false_tracks']}" for k, v in abl.items()))
    print(f"wrote {Path(stage.shown) / md.name} and its plots")
    if settings_path is not None:
        try:
            write_settings(base, settings, settings_path, source=str(args.scenario))
        except ConfigError as err:
            if err.path == "--write-settings":
                raise
            raise ConfigError("--write-settings", str(err)) from None
        print(f"wrote {settings_path} ({', '.join(f'{k} = {v}' for k, v in settings.items())})")
    return 0


def _characterise(scn, data: dict, out: Path, args: argparse.Namespace):
    """The perception characterisation of ``scn``, its ablation runs and the report written into ``out``:
    (characterisation, ablation or None, measured settings, report path)."""
    from tqdm import tqdm

    from ..perception.characterise import ABLATION, ablation, characterise, measured_settings
    from ..perception.report import write_report

    with tqdm(total=scn.n_frames, desc=f"{scn.name} perception", unit="frame", disable=args.quiet or None,
              leave=False) as bar:
        ch = characterise(scn, on_frame=frame_progress(bar), merge_sweep=not args.no_merge_sweep)
    abl = None
    if not args.no_ablation:
        with tqdm(total=len(ABLATION), desc=f"{scn.name} tracker runs", unit="run", disable=args.quiet or None,
                  leave=False) as bar:
            abl = ablation(data, on_run=lambda name: (bar.set_postfix_str(name), bar.update(1)))
    settings = measured_settings(ch)
    note = f"Scenario `{scn.name}`, seed {scn.seed}, {scn.duration_s:g} s, pipeline `{scn.sensor.pipeline}`, " \
           f"LiDAR preset `{scn.sensor.lidar.preset}`."
    return ch, abl, settings, write_report(ch, out, abl, settings, note=note)


def _cmd_scenarios(args: argparse.Namespace) -> int:
    from ..scenario.spec import SCENARIO_DIR, list_scenarios
    from ..world import load_scenario

    for name in list_scenarios():
        try:
            scn = load_scenario(SCENARIO_DIR / f"{name}.toml")
            if scn.env is not None:
                cars, road = "env traffic", scn.env.id
            elif scn.traffic.enabled:
                cars, road = f"{len(scn.all_vehicles()):2d} + traffic", scn.road.kind
            else:
                cars, road = f"{len(scn.all_vehicles()):2d} cars", scn.road.kind
            print(f"{name:<18} {scn.duration_s:6.0f} s  {cars:<12} {road:<14} {scn.tracker.name:<10} "
                  f"{scn.description}")
        except ConfigError as err:
            print(f"{name:<16} INVALID: {err}")
    return 0


def _cmd_trackers(args: argparse.Namespace) -> int:
    from roadtrack.trackers import describe_tracker, named_trackers, plugin_trackers

    from ..tracking import named_trackers as whole_trackers

    for name in named_trackers(all_combinations=args.all):
        print(f"{name:<22} {describe_tracker(name)}")
    plugged = [n for n in plugin_trackers() if args.all or n not in named_trackers()]
    if plugged and not args.all:
        print("\nwith installed plug-in filters and associators (entry points roadtrack.filters, .associators):")
        for name in plugged:
            print(f"{name:<22} {describe_tracker(name)}")
    print("\nwhole trackers (testbed run --tracker NAME; not in scenario files' tracker.name):")
    for t in whole_trackers().values():
        print(f"{t.name:<22} {t.doc} [{t.source}]")
    return 0


def _cmd_warmup(args: argparse.Namespace) -> int:
    from ..pipeline.warmup import main as warm

    return warm()


def _cmd_keys(args: argparse.Namespace) -> int:
    from .keys import keys_markdown

    sys.stdout.write(keys_markdown())
    return 0


def _add_run_parser(sub) -> None:
    """Add ``run`` (scenario, tracker, overrides, output and recording options) to the sub-commands."""
    r = sub.add_parser("run", help="run a scenario end to end: recording, tables, scores")
    r.add_argument("scenario", help="scenario file, or the name of a shipped one (see `testbed scenarios`)")
    r.add_argument("--tracker", help="tracker name overriding the scenario's, e.g. jpda-kf (see `testbed trackers`), or "
                                     "your own tracker class: my_module:MyTracker or path/to/file.py:MyTracker "
                                     "(docs/api.md)")
    r.add_argument("--seed", type=int, help="seed overriding the scenario's")
    r.add_argument("--set", action="append", metavar="KEY=VALUE",
                   help="override any scenario key by its dotted path, e.g. --set duration_s=5 "
                        "--set sensor.clutter.density_per_m2=0.01 (repeatable)")
    r.add_argument("--out", help="output folder (default runs/<scenario>)")
    r.add_argument("--policy", metavar="MODULE:FUNCTION", help="your own ego policy for a scenario with [env]: "
                   "f(observation, info) -> action, from an importable module or a file (path/to/file.py:f); "
                   "replaces the file's env.policy (a scenario file itself names no code)")
    r.add_argument("--record", metavar="LEVEL", help="what the recording keeps, overriding the scenario's "
                   "record.level: full (every LiDAR point), default (the point cloud thinned), light (no point "
                   "cloud), tracks (truth and tracks only); see README, Output files")
    r.add_argument("--no-record", action="store_true", help="skip the rerun recording")
    r.add_argument("--no-plot", action="store_true",
                   help="skip timeline.png (each car seen as a bar coloured by the track covering it, and its error)")
    r.add_argument("--quiet", action="store_true", help="no progress bar")
    r.set_defaults(func=_cmd_run)


def _version() -> str:
    """The installed roadtrack's version (pyproject.toml), or "unknown" when it is run from a bare checkout."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("roadtrack")
    except PackageNotFoundError:
        return "unknown (not installed)"


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog="testbed", description="roadtrack: simulator-coupled target tracking testbed")
    p.add_argument("--version", action="version", version=f"roadtrack {_version()}")
    p.add_argument("--debug", action="store_true", help="show the traceback of an error (also accepted after "
                   "the command)")
    sub = p.add_subparsers(dest="command", required=True)
    _add_run_parser(sub)
    sc = sub.add_parser("score", help="score a run's tracks, or any tracks table (CSV or parquet, e.g. from another "
                                      "program), against the run's truth")
    sc.add_argument("run", help="a run folder (testbed run ... --out RUN)")
    sc.add_argument("--tracks", help="a tracks table to score instead of the run's: frame (or time), track_id (or "
                                     "id), x, y, optional vx, vy, status (docs/api.md)")
    sc.add_argument("--json", action="store_true", help="print the scores as JSON")
    sc.set_defaults(func=_cmd_score)
    c = sub.add_parser("perception", help="characterise the perception on a scenario: P_D, centre error, merges, "
                       "splits, clutter, ground (markdown + PNG report)")
    c.add_argument("scenario", help="scenario file, or the name of a shipped one")
    c.add_argument("--seed", type=int, help="seed overriding the scenario's")
    c.add_argument("--duration", type=float, help="simulated seconds overriding the scenario's duration_s")
    c.add_argument("--set", action="append", metavar="KEY=VALUE", help="override any scenario key (repeatable)")
    c.add_argument("--out", help="report folder (default runs/perception/<scenario>)")
    c.add_argument("--write-settings", metavar="FILE", help="write a copy of the scenario (with its --set keys, "
                   "not --seed or --duration) with the measured P_D, clutter density and sigma_w as its tracker "
                   "settings; an existing FILE is replaced only if this option wrote it")
    c.add_argument("--no-ablation", action="store_true", help="skip the tracker runs that count the false tracks "
                   "each static-object method removes")
    c.add_argument("--no-merge-sweep", action="store_true", help="skip the synthetic two-car merge-vs-gap sweep")
    c.add_argument("--quiet", action="store_true", help="no progress bars")
    c.set_defaults(func=_cmd_perception)
    v = sub.add_parser("view", help="open the rerun viewer on a run's recording")
    v.add_argument("run_dir", help="run folder (or .rrd file)")
    v.add_argument("--web", action="store_true", help="serve the web viewer on 127.0.0.1 instead of a window")
    v.add_argument("--port", type=port_arg, help=f"port of the web viewer (default {WEB_VIEWER_PORT}), or of the "
                   "native viewer's server (default: rerun's, 9876); refused if in use")
    v.add_argument("--at", type=at_arg, metavar="SECONDS", help="open the recording at this simulated time, "
                   "paused (0 .. the recording's end)")
    v.add_argument("--event", type=event_arg, metavar="N", help="open the recording at the run's event N "
                   "(numbered as `testbed run` lists them, from events.parquet), paused")
    v.set_defaults(func=cmd_view)
    ch = sub.add_parser("check", help="validate a scenario or campaign file fully without running it (one line)")
    ch.add_argument("file", help="scenario or campaign file, or the name of a shipped one")
    ch.add_argument("--set", action="append", metavar="KEY=VALUE", help="override a scenario key (repeatable)")
    ch.set_defaults(func=cmd_check)
    s = sub.add_parser("scenarios", help="list the shipped scenarios")
    s.set_defaults(func=_cmd_scenarios)
    k = sub.add_parser("keys", help="print every scenario key with its default and meaning (markdown)")
    k.set_defaults(func=_cmd_keys)
    warm_help = ("compile the sensors' numba kernels into their cache now, not in the first run after an install "
                 "or an update (about a minute; a few seconds when the cache is warm)")
    w = sub.add_parser("warmup", help=warm_help, description=warm_help[0].upper() + warm_help[1:] + ".")
    w.set_defaults(func=_cmd_warmup)
    t = sub.add_parser("trackers", help="list the tracker names, one line each")
    t.add_argument("--all", action="store_true", help="every associator x filter (x wrapper) combination, "
                   "not only the papers' named trackers")
    t.set_defaults(func=_cmd_trackers)
    from .campaign import add_campaign_parser

    add_campaign_parser(sub)
    from .reproduce import add_reproduce_parser

    add_reproduce_parser(sub)
    from .export import add_export_parser

    add_export_parser(sub)
    from .replay import add_replay_parser

    add_replay_parser(sub, _cmd_replay)
    _debug_everywhere(p)
    return p


def _debug_everywhere(parser: argparse.ArgumentParser) -> None:
    """Accept ``--debug`` after any (sub-)command too (unset unless given, so it never hides the global one)."""
    for action in parser._actions:  # noqa: SLF001 - argparse has no public walk over sub-parsers
        if isinstance(action, argparse._SubParsersAction):  # noqa: SLF001
            for child in dict.fromkeys(action.choices.values()):
                if "--debug" not in child._option_string_actions:  # noqa: SLF001
                    child.add_argument("--debug", action="store_true", default=argparse.SUPPRESS,
                                       help="show the traceback of an error")
                _debug_everywhere(child)


@contextlib.contextmanager
def _one_line_warnings(debug: bool):
    """Warnings as ``warning: MESSAGE`` lines (the default format, with the source line, under ``--debug``)."""
    previous = warnings.showwarning

    def show(message, category, filename, lineno, file=None, line=None) -> None:
        print(f"warning: {one_line(message) if isinstance(message, Warning) else message}",
              file=file or sys.stderr)

    if not debug:
        warnings.showwarning = show
    try:
        yield
    finally:
        warnings.showwarning = previous


def replace_unencodable_output() -> None:
    """Print a character the terminal's encoding cannot show (``PYTHONIOENCODING=ascii``) as ``\\xa7``, not
    fail with UnicodeEncodeError: stdout and stderr, when they are text streams."""
    for stream in (sys.stdout, sys.stderr):
        reconfigure = getattr(stream, "reconfigure", None)
        if reconfigure is not None:
            with contextlib.suppress(ValueError, OSError):  # closed, or not reconfigurable: left as it is
                reconfigure(errors="backslashreplace")


def main(argv: list[str] | None = None) -> int:
    """``testbed ...``: every error one line on stderr and exit code 1 (run time), 2 (input), or 128 + the signal
    for Ctrl-C (130), SIGTERM (143) and SIGHUP (129), which keep the finished work like Ctrl-C (see
    :mod:`testbed.common.errors`); ``--debug`` adds the traceback."""
    replace_unencodable_output()
    one_thread_per_process()  # before numpy and open3d are imported (testbed/common/threads.py)
    os.environ.setdefault("RERUN_ANALYTICS", "0")  # before rerun is imported (rerun 0.41 ignores it, see view)
    try:
        args = build_parser().parse_args(argv)
    except SystemExit as stop:  # --help, or a usage error already printed as one line
        return stop.code if isinstance(stop.code, int) else (0 if stop.code is None else 2)
    debug = bool(getattr(args, "debug", False))
    from ..pipeline.warmup import first_compile_note

    # a command that compiles numba kernels (the first run after an install, without `testbed warmup`) says so once
    note = contextlib.nullcontext() if args.command == "warmup" else first_compile_note()
    with _one_line_warnings(debug), note:
        return guarded(args.func, args, debug)


if __name__ == "__main__":
    sys.exit(main())
