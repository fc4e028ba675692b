"""Campaign files: typed, frozen, strict (``campaigns/*.toml``), and the run plan they expand to.

A campaign is scenarios x trackers x grid points x seeds. Every scenario or tracker key is addressed by
its dotted path (``sensor.clutter.density_per_m2``, ``convoy.gap_m``, ``tracker.filter.sigma_v``); TOML
lets it be written bare (``sensor.clutter.density_per_m2 = [...]``, a nested table) or quoted, both mean
the same. :func:`load_campaign` loads every scenario with every override and grid value before any run,
so a bad key or value fails at once with a one-line :class:`~testbed.config.strict.ConfigError` naming the
campaign file and the dotted key, e.g.
``campaigns/x.toml: grid."sensor.clutter.density_per_m2"[2]: sensor.clutter.density_per_m2: -1.0 is not
allowed; must be >= 0 (scenario cut_in_out, tracker jpda-kf)``.

Common random numbers: the scenario seed of a run depends only on (``base_seed``, scenario name, seed
index) (:func:`run_seed`), never on the tracker, the grid values or the scheduling, so trackers and
parameter values are compared on the same traffic and the same noise, and a campaign gives the same
numbers on any number of workers.
"""
from __future__ import annotations

import itertools
import json
import re
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..config import (ConfigError, field, find_file, from_dict, one_line, positive, read_toml_file, shipped_dir,
                      to_dict)
from ..config.limits import at_most, check_campaign_size, check_folder_name, seed_field

CAMPAIGN_DIR = shipped_dir("campaign")
"""The shipped campaigns' folder (testbed/config/files.py, :func:`~testbed.config.files.shipped_dir`)."""

# Keys a campaign may not set through `overrides` or `grid`: the seed is derived per run (common random
# numbers), the tracker is the `trackers` axis, and the scenario name keys the seeds and the results.
FORBIDDEN_KEYS = {"seed": "the seed of every run is derived from base_seed, the scenario and the seed index",
                  "name": "the scenario name identifies its runs and seeds",
                  "tracker": "set trackers with `trackers` and tracker parameters with tracker.filter.<name>, tracker.associator.<name>, tracker.management.<name>",
                  "tracker.name": "set trackers with `trackers`"}

# Columns of the results table that a grid key may not shadow.
RESERVED_COLUMNS = ("run_id", "run_index", "campaign", "scenario", "tracker", "grid_index", "seed_index", "seed",
                    "status", "error_type", "error", "error_where", "warnings", "wall_s", "worker", "finished_at",
                    "n_frames", "dt_s", "recorded", "series_pos_rmse_m")

# Above this many (scenario, tracker, grid point) combinations only every single grid value is validated.
MAX_VALIDATED_COMBINATIONS = 5000


@dataclass(frozen=True)
class RecordOptions:
    full_seeds: tuple[int, ...] = field((), doc="seed indices whose runs also write full recordings (run.rrd, "
                                        "parquet tables, scores.json) to DIR/recordings/<run_id>/; default: "
                                        "scores only", check=(lambda v: all(s >= 0 for s in v), "seed indices >= 0"))


@dataclass(frozen=True)
class CampaignFile:
    """What a campaign TOML file holds (validated key by key by :func:`testbed.config.strict.from_dict`)."""

    scenarios: tuple[str, ...] = field(doc="shipped scenario names or scenario files (relative to the campaign "
                                       "file)", check=(lambda v: len(v) > 0, "a non-empty list"))
    trackers: tuple[str, ...] = field(doc="tracker names, see `testbed trackers`",
                                      check=(lambda v: len(v) > 0, "a non-empty list"))
    seeds: int = field(doc="runs per (scenario, tracker, grid point): seed indices 0..seeds-1", **positive(),
                       **at_most("campaign_seeds"))
    name: str = field("", doc="campaign name, also its folder runs/campaigns/<name> (letters, digits, '.', '_', "
                      "'-'; default: the file name without .toml)")
    description: str = field("", doc="one-line description")
    base_seed: int = field(0, doc="campaign seed: run seeds derive from (base_seed, scenario name, seed index)",
                           **seed_field())
    overrides: dict[str, Any] = field({}, doc="dotted scenario keys set for every run, e.g. duration_s = 5.0")
    grid: dict[str, Any] = field({}, doc="dotted scenario keys -> list of values; runs cover the full product")
    record: RecordOptions = field(RecordOptions(), doc="what to record besides the scores")
    baseline: str = field("", doc="tracker the report's paired differences are taken against (paired by scenario, "
                          "grid point and seed); default: jpda-kf when it is among the trackers, else the first")


@dataclass(frozen=True)
class ScenarioSource:
    """A campaign scenario: its name (the scenario file's ``name``), the entry that named it, its TOML dict."""

    name: str
    entry: str
    data: dict


@dataclass(frozen=True)
class Campaign:
    """A loaded, validated campaign. ``grid`` is ((dotted key, (value, ...)), ...) in file order."""

    name: str
    description: str
    base_seed: int
    seeds: int
    scenarios: tuple[ScenarioSource, ...]
    trackers: tuple[str, ...]
    overrides: dict
    grid: tuple[tuple[str, tuple], ...]
    record: RecordOptions
    source: str = ""
    baseline: str = ""

    @property
    def baseline_tracker(self) -> str:
        """The tracker of the paired differences: ``baseline``, else jpda-kf if run, else the first tracker."""
        return self.baseline or ("jpda-kf" if "jpda-kf" in self.trackers else self.trackers[0])

    @property
    def grid_keys(self) -> tuple[str, ...]:
        return tuple(k for k, _ in self.grid)

    @property
    def n_runs(self) -> int:
        n = len(self.scenarios) * len(self.trackers) * self.seeds
        for _, values in self.grid:
            n *= len(values)
        return n


@dataclass(frozen=True)
class RunSpec:
    """One run of the plan. ``params``: grid key -> the value as written; ``grid_index``: index of each
    value in its grid list; ``columns``: grid key -> value for the results table (see :func:`column_values`)."""

    run_index: int
    run_id: str
    scenario: str
    tracker: str
    grid_index: tuple[int, ...]
    params: dict
    columns: dict
    seed_index: int
    seed: int
    record_full: bool


def run_seed(base_seed: int, scenario_name: str, seed_index: int) -> int:
    """Scenario seed of run (scenario, seed index): independent of tracker, parameters and scheduling.

    ``SeedSequence([base_seed, crc32(name), seed_index]).generate_state(1)[0]``, a uint32.
    """
    import numpy as np

    ss = np.random.SeedSequence([int(base_seed), zlib.crc32(scenario_name.encode("utf-8")), int(seed_index)])
    return int(ss.generate_state(1)[0])


def _flatten(table: dict, prefix: str, leaf_is_list: bool, where: str) -> dict[str, Any]:
    """Nested TOML tables -> {dotted key: value}. Grids stop at lists, overrides at any non-table."""
    out: dict[str, Any] = {}
    for key, value in table.items():
        dotted = f"{prefix}.{key}" if prefix else str(key)
        if isinstance(value, dict) and value:
            out.update(_flatten(value, dotted, leaf_is_list, where))
            continue
        if leaf_is_list:
            if not isinstance(value, list):
                raise ConfigError(f'{where}."{dotted}"', f"expected a list of values, got {value!r}")
            if not value:
                raise ConfigError(f'{where}."{dotted}"', "empty list; give at least one value")
        out[dotted] = value
    return out


def _check_key(key: str, where: str) -> None:
    for bad, why in FORBIDDEN_KEYS.items():
        if key == bad or (bad != "tracker" and key.startswith(bad + ".")):
            raise ConfigError(f'{where}."{key}"', f"cannot be set by a campaign: {why}")
    parts = key.split(".")
    if any(p == "" for p in parts):
        raise ConfigError(f'{where}."{key}"', "not a dotted key (empty part)")


def _address_error(resolved: dict, key: str) -> str | None:
    """Why ``key`` cannot address a value of the resolved scenario dict (None when it can).

    Every table on the way must exist: setting ``convoy.gap_m`` on a scenario without a convoy would
    otherwise create a whole default convoy. To add a table, give it whole as a grid value
    (``convoy = [{...}]``).
    """
    node: Any = resolved
    parts = key.split(".")
    for i, part in enumerate(parts[:-1]):
        here = ".".join(parts[: i + 1])
        if isinstance(node, dict):
            if part not in node:
                return f"{here}: unknown key; allowed: {', '.join(sorted(node))}"
            node = node[part]
            if node is None:
                return (f"{here} is not set in this scenario (to add it, give the whole table as a grid value: "
                        f"{here} = [{{...}}])")
        elif isinstance(node, list):
            if not part.isdigit() or int(part) >= len(node):
                return f"{here}: no item {part!r}; allowed: 0..{len(node) - 1}"
            node = node[int(part)]
        else:
            return f"{here}: {node!r} has no keys"
    last = parts[-1]
    if isinstance(node, list) and (not last.isdigit() or int(last) >= len(node)):
        return f"{key}: no item {last!r}; allowed: 0..{len(node) - 1}"
    if not isinstance(node, (dict, list)):
        return f"{'.'.join(parts[:-1])}: {node!r} has no keys"
    return None


TRACKER_TABLES = ("tracker.filter.", "tracker.associator.", "tracker.management.")
NAMED_SETTINGS = "jpda-kf"
"""The combination whose tracker tables configure a named tracker's runs (Stone Soup's read jpda-kf's settings)."""


def settings_tracker(tracker: str) -> str:
    """The built-in combination a run of ``tracker`` sets as ``tracker.name``: ``tracker`` itself, or for a named
    tracker (Stone Soup's, an installed plug-in's: testbed.tracking.registry) :data:`NAMED_SETTINGS`."""
    from ..tracking.registry import is_named

    return NAMED_SETTINGS if is_named(tracker) else tracker


def for_tracker(params: dict[str, Any], tracker: str) -> dict[str, Any]:
    """``params`` without the tracker-table keys (``tracker.filter.X``, ...) that ``tracker`` does not have, so a
    grid over, e.g., ``tracker.associator.max_events`` can compare JPDA with GNN (GNN runs without the key)."""
    from roadtrack.trackers.registry import known_keys

    known = known_keys(settings_tracker(tracker))
    out = {}
    for key, value in params.items():
        table = next((t for t in TRACKER_TABLES if key.startswith(t)), None)
        if table is None or key[len(table):].split(".")[0] in known[table.split(".")[1]]:
            out[key] = value
    return out


def _check_tracker_keys(keys: list[tuple[str, str]], trackers: tuple[str, ...]) -> None:
    """A tracker-table key must belong to at least one of the campaign's trackers."""
    from roadtrack.trackers.registry import known_keys

    known = [known_keys(settings_tracker(t)) for t in trackers]
    for where, key in keys:
        table = next((t for t in TRACKER_TABLES if key.startswith(t)), None)
        if table is None:
            continue
        role, name = table.split(".")[1], key[len(table):].split(".")[0]
        if not any(name in k[role] for k in known):
            from roadtrack.trackers import ASSOCIATORS, FILTERS

            kinds = set(FILTERS) | set(ASSOCIATORS)  # per-kind sub-tables, accepted by every tracker
            allowed = sorted(set().union(*(k[role] for k in known)) - {"kind"} - kinds)
            raise ConfigError(f'{where}."{key}"', f"no tracker of this campaign has {role} parameter {name!r}; "
                              f"allowed: {', '.join(allowed)}")


def _scenario(data: dict, overrides: dict[str, Any], tracker: str, worlds: set[str]):
    """The scenario of ``data`` with ``overrides`` for ``tracker``, checked (testbed.world.parse_scenario). The world
    check (an ``[env]`` scenario builds its environment and takes a step: most of a campaign check's time) reads no
    tracker setting, so it runs once per scenario that differs in anything but its tracker table: ``worlds`` holds
    the ones checked so far, for one campaign."""
    from ..scenario.spec import apply_overrides, parse_scenario
    from ..world import check_world

    scn = parse_scenario(apply_overrides(data, {**for_tracker(overrides, tracker),
                                                "tracker.name": settings_tracker(tracker)}))
    world = json.dumps({k: v for k, v in to_dict(scn).items() if k != "tracker"}, sort_keys=True, default=repr)
    if world not in worlds:
        check_world(scn)
        worlds.add(world)
    return scn


def column_values(values: tuple) -> tuple:
    """Values of one grid key as stored in its results column: numbers as float64 when any is a float
    (int64 when all are integers), strings and booleans as they are; anything else (tables, lists, mixed
    kinds) as canonical JSON text."""
    kinds = {type(v) for v in values}
    if kinds <= {int, float} and kinds:
        return tuple(float(v) for v in values) if float in kinds else tuple(int(v) for v in values)
    if kinds in ({str}, {bool}):
        return tuple(values)
    return tuple(json.dumps(v, sort_keys=True, default=str) for v in values)


def _safe(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.+-]", "_", text)


def _load_sources(spec: "CampaignFile", base_dir: Path | None,
                  scenario_data: dict[str, dict] | None) -> list[ScenarioSource]:
    """Each scenario entry loaded as it is (a broken scenario file is reported at its entry)."""
    from ..scenario.spec import read_toml
    from ..world import parse_scenario

    sources: list[ScenarioSource] = []
    for i, entry in enumerate(spec.scenarios):
        where = f"scenarios[{i}]"
        if scenario_data is not None and entry in scenario_data:
            raw = scenario_data[entry]
        else:
            path = Path(entry)
            if base_dir is not None and not path.is_absolute() and _is_file(base_dir / path):
                path = base_dir / path
            try:
                raw = read_toml(path)
            except ConfigError as err:
                raise ConfigError(where, str(err)) from None
        try:
            scn = parse_scenario(raw)
        except ConfigError as err:
            raise ConfigError(where, f"scenario {entry}: {err}") from None
        if any(_safe(s.name) == _safe(scn.name) for s in sources):
            raise ConfigError(where, f"scenario name {scn.name!r} appears twice (names key the run ids)")
        sources.append(ScenarioSource(scn.name, entry, raw))
    return sources


def _is_file(path: Path) -> bool:
    """``path.is_file()``, False where the system refuses the path (too long, NUL): read_toml reports it."""
    try:
        return path.is_file()
    except (OSError, ValueError):
        return False


def _check_trackers(trackers: tuple[str, ...]) -> None:
    """Each a built-in combination or a named tracker (Stone Soup's, a plug-in's), loadable now, and once."""
    from roadtrack.trackers import parse_tracker_name

    from ..tracking.registry import is_named
    from ..tracking.user import load_tracker

    for i, tracker in enumerate(trackers):
        try:
            if is_named(tracker):
                load_tracker(tracker)  # a missing Stone Soup is this entry's one-line error
            else:
                parse_tracker_name(tracker)
        except ConfigError as err:
            raise ConfigError(f"trackers[{i}]", str(err)) from None
        except ValueError as err:
            raise ConfigError(f"trackers[{i}]", one_line(err) or type(err).__name__) from None
        if tracker in trackers[:i]:
            raise ConfigError(f"trackers[{i}]", f"tracker {tracker!r} appears twice")


def _check_keys(overrides: dict[str, Any], grid: dict[str, Any], trackers: tuple[str, ...]) -> None:
    for key in overrides:
        _check_key(key, "overrides")
    for key in grid:
        _check_key(key, "grid")
        if key in RESERVED_COLUMNS:
            raise ConfigError(f'grid."{key}"',
                              f"clashes with a results column; reserved: {', '.join(RESERVED_COLUMNS)}")
    keys = [("overrides", k) for k in overrides] + [("grid", k) for k in grid]
    _check_tracker_keys(keys, trackers)
    for (wa, a), (wb, b) in itertools.combinations(keys, 2):
        if a == b or b.startswith(a + ".") or a.startswith(b + "."):
            raise ConfigError(f'{wb}."{b}"', f"overlaps {wa}.\"{a}\": set each value once")


def _context(src: ScenarioSource, tracker: str) -> str:
    return f" (scenario {src.name}, tracker {tracker})"


def _check_overrides(sources: list[ScenarioSource], overrides: dict[str, Any], trackers: tuple[str, ...],
                     worlds: set[str]) -> None:
    """Each override alone (precise blame), then all together, for every scenario and tracker."""
    from ..scenario.spec import parse_scenario

    for src in sources:
        resolved = to_dict(parse_scenario(src.data))
        for key, value in overrides.items():
            why = _address_error(resolved, key)
            if why is not None:
                raise ConfigError(f'overrides."{key}"', f"{why} (scenario {src.name})")
            for tracker in trackers:
                try:
                    _scenario(src.data, {key: value}, tracker, worlds)
                except ConfigError as err:
                    raise ConfigError(f'overrides."{key}"', f"{err}{_context(src, tracker)}") from None
        for tracker in trackers:
            try:
                _scenario(src.data, overrides, tracker, worlds)
            except ConfigError as err:
                raise ConfigError("overrides", f"{err}{_context(src, tracker)}") from None


def _check_grid(sources: list[ScenarioSource], overrides: dict[str, Any], grid: dict[str, Any],
                trackers: tuple[str, ...], worlds: set[str]) -> None:
    """Each grid value alone on top of the overrides, then (if not too many) every combination."""
    from ..scenario.spec import apply_overrides, parse_scenario

    for src in sources:
        resolved = to_dict(parse_scenario(apply_overrides(src.data, for_tracker(overrides, trackers[0]))))
        for key, values in grid.items():
            why = _address_error(resolved, key)
            if why is not None:
                raise ConfigError(f'grid."{key}"', f"{why} (scenario {src.name})")
            for j, value in enumerate(values):
                for tracker in trackers:
                    try:
                        _scenario(src.data, {**overrides, key: value}, tracker, worlds)
                    except ConfigError as err:
                        raise ConfigError(f'grid."{key}"[{j}]', f"{err}{_context(src, tracker)}") from None
    n_points = 1
    for values in grid.values():
        n_points *= len(values)
    if len(grid) < 2 or n_points * len(sources) * len(trackers) > MAX_VALIDATED_COMBINATIONS:
        return
    for src in sources:
        for combo in itertools.product(*grid.values()):
            point = dict(zip(grid, combo))
            for tracker in trackers:
                try:
                    _scenario(src.data, {**overrides, **point}, tracker, worlds)
                except ConfigError as err:
                    text = ", ".join(f"{k}={v!r}" for k, v in point.items())
                    raise ConfigError("grid", f"combination {text}: {err}{_context(src, tracker)}") from None


def parse_campaign(data: dict, source: str = "<dict>", base_dir: Path | None = None,
                   scenario_data: dict[str, dict] | None = None, default_name: str | None = None) -> Campaign:
    """Build and validate a :class:`Campaign` from a TOML dict (errors without the file prefix).

    ``scenario_data`` maps scenario entries to their TOML dicts (a results directory keeps the ones a
    campaign started with, so a resumed campaign runs the same scenarios even if the files changed).
    """
    spec: CampaignFile = from_dict(CampaignFile, data)
    name = _campaign_name(spec.name or default_name or Path(source).stem, given=bool(spec.name))
    overrides = _flatten(spec.overrides, "", False, "overrides")
    grid = _flatten(spec.grid, "", True, "grid")
    check_campaign_size(spec.seeds, len(spec.scenarios), len(spec.trackers), {k: len(v) for k, v in grid.items()})
    sources = _load_sources(spec, base_dir, scenario_data)
    _check_trackers(spec.trackers)
    _check_keys(overrides, grid, spec.trackers)
    worlds: set[str] = set()  # the worlds checked (see _scenario)
    _check_overrides(sources, overrides, spec.trackers, worlds)
    _check_grid(sources, overrides, grid, spec.trackers, worlds)
    for i, s in enumerate(spec.record.full_seeds):
        if s >= spec.seeds:
            raise ConfigError(f"record.full_seeds[{i}]", f"{s} is not a seed index; allowed: 0..{spec.seeds - 1}")
    if spec.baseline and spec.baseline not in spec.trackers:
        raise ConfigError("baseline", f"{spec.baseline!r} is not one of the campaign's trackers "
                                      f"({', '.join(spec.trackers)})")
    return Campaign(name=name, description=spec.description, base_seed=spec.base_seed, seeds=spec.seeds,
                    scenarios=tuple(sources), trackers=spec.trackers, overrides=overrides,
                    grid=tuple((k, tuple(v)) for k, v in grid.items()), record=spec.record, source=source,
                    baseline=spec.baseline)


def _campaign_name(name: str, given: bool) -> str:
    """``name`` checked as a folder name (``given``: set by the file, else taken from the file name)."""
    try:
        return check_folder_name(name, "name")
    except ConfigError as err:
        if given:
            raise
        raise ConfigError("name", f"{str(err).split(': ', 1)[-1]} (the name defaults to the file name; set "
                          "name = \"...\" in the file)") from None


def read_campaign_toml(path: str | Path) -> tuple[Path, dict]:
    """The TOML dict of a campaign file (a path, or the name of a shipped campaign); a missing, unreadable,
    non-UTF-8 or malformed file is a one-line ConfigError naming it."""
    found = find_file(path, "campaign")
    return found, read_toml_file(found)


def load_campaign(path: str | Path, scenario_data: dict[str, dict] | None = None,
                  default_name: str | None = None) -> Campaign:
    """Load and validate a campaign file (a path or a shipped campaign's name); every error is one line
    starting with the file path. ``name`` defaults to ``default_name``, else the file name."""
    path, data = read_campaign_toml(path)
    try:
        return parse_campaign(data, str(path), base_dir=path.parent, scenario_data=scenario_data,
                              default_name=default_name)
    except ConfigError as err:
        out = ConfigError("", f"{path}: {err}")
        out.path = err.path
        raise out from None


def plan(campaign: Campaign) -> list[RunSpec]:
    """Every run of the campaign, in (scenario, tracker, grid point, seed index) order.

    ``run_id`` = ``<scenario>--<tracker>[--g<i>.<j>...]--s<seed index>``, with one grid index per key.
    """
    keys = campaign.grid_keys
    columns = [column_values(values) for _, values in campaign.grid]
    width = max(3, len(str(campaign.seeds - 1)))
    full = set(campaign.record.full_seeds)
    out: list[RunSpec] = []
    for src in campaign.scenarios:
        seeds = [run_seed(campaign.base_seed, src.name, k) for k in range(campaign.seeds)]
        for tracker in campaign.trackers:
            for gidx in itertools.product(*(range(len(v)) for _, v in campaign.grid)):
                params = {k: campaign.grid[i][1][j] for i, (k, j) in enumerate(zip(keys, gidx))}
                cols = {k: columns[i][j] for i, (k, j) in enumerate(zip(keys, gidx))}
                gpart = f"--g{'.'.join(map(str, gidx))}" if keys else ""
                for k in range(campaign.seeds):
                    run_id = f"{_safe(src.name)}--{_safe(tracker)}{gpart}--s{k:0{width}d}"
                    out.append(RunSpec(run_index=len(out), run_id=run_id, scenario=src.name, tracker=tracker,
                                       grid_index=tuple(gidx), params=params, columns=cols, seed_index=k,
                                       seed=seeds[k], record_full=k in full))
    ids = [r.run_id for r in out]
    if len(set(ids)) != len(ids):
        raise ConfigError("scenarios", "two scenario or tracker names map to the same run id; rename one")
    return out
