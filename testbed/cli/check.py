"""``testbed check FILE [--set KEY=VALUE ...]``: validate a scenario or campaign file without running it."""
from __future__ import annotations

import argparse
from pathlib import Path

from ..config import ConfigError

def cmd_check(args: argparse.Namespace) -> int:
    """Validate a scenario file (with ``--set``) or a campaign file fully without running it; one line."""
    from ..config import parse_sets

    print(_check_file(args.file, parse_sets(args.set or [])))
    return 0


def _check_file(name: str, overrides: dict) -> str:
    """The one-line summary of a valid scenario or campaign file (ConfigError otherwise). A campaign is told
    by its top-level keys (``scenarios``, ``trackers``), which no scenario has."""
    from ..scenario.spec import read_toml
    from ..world import load_scenario

    path = Path(name)
    try:
        data = read_toml(path)
    except ConfigError:
        if path.is_file() or not _is_shipped_campaign(name):
            raise
        data = {"scenarios": None}
    if "scenarios" in data or "trackers" in data:
        if overrides:
            raise ConfigError("--set", "applies to scenario files; this is a campaign file")
        return _campaign_summary(path)
    scn = load_scenario(path, overrides)
    scn.tracker.build(scn.tracker.name)
    if scn.env is not None:
        cars = f"highway-env {scn.env.id} traffic"
    else:
        cars = f"{len(scn.all_vehicles())} vehicles" + (" + background traffic" if scn.traffic.enabled else "")
    return f"{name}: scenario {scn.name!r} OK: {scn.n_frames} frames ({scn.duration_s:g} s at {scn.rate_hz:g} Hz), " \
           f"{cars}, {scn.sensor.lidar.n_rays:,} rays per scan, tracker {scn.tracker.name}"


def _is_shipped_campaign(name: str) -> bool:
    from ..campaign.spec import CAMPAIGN_DIR

    return Path(name).suffix == "" and (CAMPAIGN_DIR / f"{name}.toml").is_file()


def _campaign_summary(path: Path) -> str:
    from ..campaign.spec import load_campaign

    c = load_campaign(path)
    grid = 1
    for _, values in c.grid:
        grid *= len(values)
    parts = [_count(len(c.scenarios), "scenario"), _count(len(c.trackers), "tracker"), _count(grid, "grid point"),
             _count(c.seeds, "seed")]
    return f"{path}: campaign {c.name!r} OK: {_count(c.n_runs, 'run')} ({' x '.join(parts)})"


def _count(n: int, what: str) -> str:
    return f"{n:,} {what}{'' if n == 1 else 's'}"

