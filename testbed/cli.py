"""``testbed`` command line: run scenarios, view recordings, list scenarios and trackers.

Exit codes: 0 success, 2 bad input (malformed scenario, unknown tracker, missing run directory).
"""
from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
from pathlib import Path

from .config import ConfigError


def _cmd_run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from .run import run_scenario
    from .scenario import load_scenario
    from .scoring import format_table

    try:
        overrides = _parse_sets(args.set or [])
    except ConfigError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    if args.tracker is not None:
        overrides["tracker.name"] = args.tracker  # "" is refused by the loader, not silently ignored
    if args.seed is not None:
        overrides["seed"] = args.seed
    try:
        scn = load_scenario(args.scenario, overrides)
    except ConfigError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    out = Path(args.out) if args.out else Path("runs") / scn.name
    with tqdm(total=scn.n_frames, desc=f"{scn.name} [{scn.tracker.name}]", unit="frame",
              disable=args.quiet or None, leave=False) as bar:
        try:
            res = run_scenario(scn, out_dir=out, record=not args.no_record,
                               on_frame=lambda i, n: bar.update(1))
        except (ValueError, RuntimeError, ArithmeticError) as err:  # trackers' FilterError, JPDA overflow, ...
            bar.close()
            where = "; ".join(getattr(err, "__notes__", []))
            print(f"error: {type(err).__name__}: {str(err).splitlines()[0] if str(err) else ''} ({where}; "
                  f"the tables of the frames before it are in {out}/)", file=sys.stderr)
            return 1
    print(format_table({f"{scn.name}/{scn.tracker.name}": res.scores}))
    m = res.metrics
    for label, sfx in (("visible truth", ""), ("all truth    ", "_all")):
        print(f"{label}: HOTA {m['hota' + sfx]:.3f}  MOTA {m['mota' + sfx]:.3f}  MOTP {m['motp' + sfx]:.3f}  "
              f"IDF1 {m['idf1' + sfx]:.3f}  ID switches {m['id_switches' + sfx]:.0f}  GOSPA {m['gospa' + sfx]:.2f} m "
              f"(per frame: missed {m['gospa_missed' + sfx]:.2f}, false {m['gospa_false' + sfx]:.2f}, "
              f"localisation {m['gospa_localisation' + sfx]:.2f} m^2)")
    per_frame = sum(res.timings_ms.values())
    print(f"\n{res.n_frames} frames, {per_frame:.1f} ms/frame "
          f"({', '.join(f'{k} {v:.1f}' for k, v in res.timings_ms.items())})")
    written = ["scores.json", "truth.parquet", "detections.parquet", "tracks.parquet", "diagnostics.parquet"]
    if not args.no_record:
        written.insert(0, "run.rrd")
    print(f"wrote {', '.join(written)} to {out}/")
    if not args.no_record:
        print(f"view it: testbed view {out}")
    return 0


def _parse_sets(items: list[str]) -> dict:
    """``KEY=VALUE`` pairs, VALUE read as a TOML value (a bare word is a string)."""
    import tomllib

    out = {}
    for item in items:
        key, sep, raw = item.partition("=")
        if not sep or not key.strip():
            raise ConfigError("--set", f"{item!r}: expected KEY=VALUE, e.g. sensor.clutter.density_per_m2=0.01")
        try:
            value = tomllib.loads(f"v = {raw}")["v"]
        except tomllib.TOMLDecodeError:
            value = raw
        out[key.strip()] = value
    return out


def _cmd_perception(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from .characterise import ABLATION, ablation, characterise, measured_settings
    from .perception_report import write_report, write_settings
    from .scenario import apply_overrides, parse_scenario, read_toml

    try:
        base = apply_overrides(read_toml(args.scenario), _parse_sets(args.set or []))  # what --write-settings keeps
        run = {"seed": args.seed, "duration_s": args.duration}
        data = apply_overrides(base, {k: v for k, v in run.items() if v is not None})
        scn = parse_scenario(data)
    except ConfigError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    settings_path = Path(args.write_settings) if args.write_settings else None
    if settings_path is not None and not settings_path.parent.is_dir():
        print(f"error: --write-settings: folder {settings_path.parent} does not exist", file=sys.stderr)
        return 2
    out = Path(args.out) if args.out else Path("runs") / "perception" / scn.name
    with tqdm(total=scn.n_frames, desc=f"{scn.name} perception", unit="frame", disable=args.quiet or None,
              leave=False) as bar:
        ch = characterise(scn, on_frame=lambda i, n: bar.update(1), merge_sweep=not args.no_merge_sweep)
    abl = None
    if not args.no_ablation:
        with tqdm(total=len(ABLATION), desc=f"{scn.name} tracker runs", unit="run", disable=args.quiet or None,
                  leave=False) as bar:
            abl = ablation(data, on_run=lambda name: (bar.set_postfix_str(name), bar.update(1)))
    settings = measured_settings(ch)
    note = f"Scenario `{scn.name}`, seed {scn.seed}, {scn.duration_s:g} s, pipeline `{scn.sensor.pipeline}`, " \
           f"LiDAR preset `{scn.sensor.lidar.preset}`."
    md = write_report(ch, out, abl, settings, note=note)
    s = ch.summary()
    print(f"ground precision {100 * s['ground_precision']:.2f} %, recall {100 * s['ground_recall']:.2f} %; "
          f"P_D in range {s['pd_in_range']:.3f} (visible {s['pd_visible']:.3f}, occluded {s['pd_occluded']:.3f}); "
          f"split {s['split_rate']:.4f}, merge {s['merge_rate']:.4f}; clutter {s['clutter_per_frame']:.2f}/frame "
          f"({s['clutter_per_m2_road']:.2e}/m^2 of road); centre RMSE box {s['centre_rmse_box_m']:.2f} m, "
          f"centroid {s['centre_rmse_centroid_m']:.2f} m")
    if abl:
        print("false confirmed tracks: " + ", ".join(f"{k} {v['false_tracks']}" for k, v in abl.items()))
    print(f"wrote {md} and its plots")
    if settings_path is not None:
        try:
            write_settings(base, settings, settings_path, source=str(args.scenario))
        except ConfigError as err:
            print(f"error: --write-settings: {err}", file=sys.stderr)
            return 2
        print(f"wrote {settings_path} ({', '.join(f'{k} = {v}' for k, v in settings.items())})")
    return 0


def _cmd_view(args: argparse.Namespace) -> int:
    path = Path(args.run_dir)
    rrd = path if path.suffix == ".rrd" else path / "run.rrd"
    if not rrd.is_file():
        print(f"error: {rrd}: no recording (run `testbed run SCENARIO --out {path}` first)", file=sys.stderr)
        return 2
    exe = shutil.which("rerun") or str(Path(sys.executable).parent / "rerun")
    cmd = [exe, str(rrd)]
    headless = sys.platform.startswith("linux") and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))
    if headless and not args.web:
        print("no display found: serving the web viewer on 127.0.0.1 instead (open the URL rerun prints; "
              "Ctrl-C to stop)", file=sys.stderr)
    if args.web or headless:
        cmd = [exe, "--serve-web", "--bind", "127.0.0.1", str(rrd)]
    env = dict(os.environ, RERUN_ANALYTICS="0")
    return subprocess.call(cmd, env=env)


def _cmd_scenarios(args: argparse.Namespace) -> int:
    from .scenario import SCENARIO_DIR, list_scenarios, load_scenario

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
    from trackers import describe_tracker, named_trackers

    for name in named_trackers(all_combinations=args.all):
        print(f"{name:<22} {describe_tracker(name)}")
    return 0


def _cmd_keys(args: argparse.Namespace) -> int:
    from .keys import keys_markdown

    sys.stdout.write(keys_markdown())
    return 0


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="testbed", description="roadtrack: simulator-coupled target tracking testbed")
    sub = p.add_subparsers(dest="command", required=True)
    r = sub.add_parser("run", help="run a scenario end to end: recording, tables, scores")
    r.add_argument("scenario", help="scenario file, or the name of a shipped one (see `testbed scenarios`)")
    r.add_argument("--tracker", help="tracker name overriding the scenario's, e.g. jpda-kf (see `testbed trackers`)")
    r.add_argument("--seed", type=int, help="seed overriding the scenario's")
    r.add_argument("--set", action="append", metavar="KEY=VALUE",
                   help="override any scenario key by its dotted path, e.g. --set duration_s=5 "
                        "--set sensor.clutter.density_per_m2=0.01 (repeatable)")
    r.add_argument("--out", help="output folder (default runs/<scenario>)")
    r.add_argument("--no-record", action="store_true", help="skip the rerun recording")
    r.add_argument("--quiet", action="store_true", help="no progress bar")
    r.set_defaults(func=_cmd_run)
    c = sub.add_parser("perception", help="characterise the perception on a scenario: P_D, centre error, merges, "
                       "splits, clutter, ground (markdown + PNG report)")
    c.add_argument("scenario", help="scenario file, or the name of a shipped one")
    c.add_argument("--seed", type=int, help="seed overriding the scenario's")
    c.add_argument("--duration", type=float, help="simulated seconds overriding the scenario's duration_s")
    c.add_argument("--set", action="append", metavar="KEY=VALUE", help="override any scenario key (repeatable)")
    c.add_argument("--out", help="report folder (default runs/perception/<scenario>)")
    c.add_argument("--write-settings", metavar="FILE", help="write a copy of the scenario (with its --set keys, "
                   "not --seed or --duration) with the measured P_D, clutter density and sigma_w as its tracker "
                   "settings")
    c.add_argument("--no-ablation", action="store_true", help="skip the tracker runs that count the false tracks "
                   "each static-object method removes")
    c.add_argument("--no-merge-sweep", action="store_true", help="skip the synthetic two-car merge-vs-gap sweep")
    c.add_argument("--quiet", action="store_true", help="no progress bars")
    c.set_defaults(func=_cmd_perception)
    v = sub.add_parser("view", help="open the rerun viewer on a run's recording")
    v.add_argument("run_dir", help="run folder (or .rrd file)")
    v.add_argument("--web", action="store_true", help="serve the web viewer on 127.0.0.1 instead of a window")
    v.set_defaults(func=_cmd_view)
    s = sub.add_parser("scenarios", help="list the shipped scenarios")
    s.set_defaults(func=_cmd_scenarios)
    k = sub.add_parser("keys", help="print every scenario key with its default and meaning (markdown)")
    k.set_defaults(func=_cmd_keys)
    t = sub.add_parser("trackers", help="list the tracker names, one line each")
    t.add_argument("--all", action="store_true", help="every associator x filter (x wrapper) combination, "
                   "not only the papers' named trackers")
    t.set_defaults(func=_cmd_trackers)
    from .campaign.cli import add_campaign_parser

    add_campaign_parser(sub)
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
