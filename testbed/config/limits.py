"""Resource bounds of scenario and campaign files, checked when a file is loaded (``docs/limits.md``).

A bad size (``convoy.count = 1000000000``, ``duration_s = 1e308``, a campaign of 10^9 runs) must fail at once
with one line, not run out of memory or time hours later. :data:`LIMITS` is the one table of named limits:
each default lets every shipped scenario and campaign pass with a margin of 2.5x or more, and the
environment variable ``ROADTRACK_MAX_<NAME>`` (e.g. ``ROADTRACK_MAX_DURATION_S=7200``) raises it. Every
refusal is a :class:`~testbed.config.strict.ConfigError` naming the key, the value, the limit and the variable:
``duration_s: 1e+09 s is above the limit 3600 s (raise it with ROADTRACK_MAX_DURATION_S)``.

Seeds are not a limit: numpy takes integers in [0, 2**32 - 1] (:func:`check_seed`). Names that become
output folders must be one plain path component (:func:`check_folder_name`).
"""
from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass
from typing import Any

from .strict import ConfigError

SEED_MAX = 2**32 - 1  # numpy's SeedSequence / RandomState accept [0, 2**32 - 1] as one 32-bit word
NAME_MAX = 100  # characters of a scenario or campaign name (an output folder)
ENV_PREFIX = "ROADTRACK_MAX_"


@dataclass(frozen=True)
class Limit:
    """One named bound: ``default`` in ``unit``; ``keys`` it applies to; ``why`` the default."""

    name: str
    default: int | float
    unit: str
    keys: str
    why: str

    @property
    def env(self) -> str:
        return ENV_PREFIX + self.name.upper()


LIMITS: dict[str, Limit] = {lim.name: lim for lim in (
    Limit("file_bytes", 10_000_000, "bytes", "size of a scenario or campaign file",
          "shipped files are < 5 kB; a bigger one is not a hand-written configuration"),
    Limit("duration_s", 3600.0, "s", "duration_s",
          "one hour; the longest shipped scenario (highway_benchmark) is 427 s"),
    Limit("rate_hz", 100.0, "Hz", "rate_hz", "spinning LiDARs turn at 5-20 Hz; shipped scenarios use 10 Hz"),
    Limit("frames", 50_000, "frames", "frames of a run, duration_s * rate_hz + 1",
          "one hour at 10 Hz plus margin; highway_benchmark has 4275"),
    Limit("physics_substeps", 100, "substeps", "physics_substeps",
          "highway-env's default envs take 15 physics ticks per 1 Hz policy step; shipped: 1"),
    Limit("road_length_m", 100_000.0, "m",
          "road.length_m, road.curve_radius_m, gaps, traffic windows and jitter (lengths along the road)",
          "100 km; the longest shipped road (highway_benchmark) is 14 km; every lane is sampled every metre"),
    Limit("offset_m", 1000.0, "m",
          "road.median_m, roadside.barrier_offset_m, sensor.lidar.mount_height_m (offsets across and above "
          "the road)", "shipped values are <= 4 m"),
    Limit("vehicles", 500, "vehicles",
          "scripted vehicles (ego + vehicles + convoy.count), traffic.count, and the background vehicles "
          "traffic.density_per_km_lane puts in the window",
          "highway-env's neighbour search is O(N^2) per tick; shipped scenarios have at most 33"),
    Limit("speed_mps", 100.0, "m/s", "every speed (vehicles, convoy, traffic ranges and jitter, "
          "road.speed_limit_mps)", "360 km/h; the fastest shipped traffic (highway_benchmark) drives 36 m/s"),
    Limit("vehicle_size_m", 50.0, "m", "length, width and height of every vehicle",
          "road trains reach 50 m; the longest shipped truck is 18.75 m"),
    Limit("roadside_objects", 200_000, "objects",
          "expected roadside boxes: barriers, posts, signs, trees, bushes along every road edge",
          "the 14 km motorway of highway_benchmark makes about 18,000"),
    Limit("lidar_beams", 512, "beams", "sensor.lidar.n_beams", "the largest preset (vls128) has 128"),
    Limit("lidar_rays", 500_000, "rays", "rays per scan, n_beams * 360 / azimuth_step_deg",
          "vls128 casts 230,400; shipped scenarios 72,000"),
    Limit("lidar_range_m", 500.0, "m",
          "sensor.lidar.max_range_m, ground_half_size_m, range_noise_std_m, sensor.clutter.radius_m, "
          "scoring distances", "the longest preset range (vls128) is 200 m"),
    Limit("clutter_points", 100_000, "points", "expected added clutter points per frame, "
          "density_per_m2 * pi * radius_m^2", "the clutter_sweep campaign adds at most about 154"),
    Limit("ransac_iterations", 100_000, "iterations", "sensor.perception.ground.ransac_iterations",
          "the default is 100"),
    Limit("box_headings", 3600, "headings", "box-fit heading grid, 90 / step_deg and 90 / coarse_step_deg "
          "(sensor.perception.boxfit)", "the defaults give 45 and 15"),
    Limit("campaign_seeds", 10_000, "seeds", "seeds of a campaign (runs per cell)",
          "the largest shipped campaign uses 20"),
    Limit("campaign_runs", 100_000, "runs", "runs of a campaign (scenarios x trackers x grid points x seeds), "
          "checked before the run list is built", "the largest shipped campaign has 273"),
)}


def _number(value: float) -> str:
    if isinstance(value, int) or (isinstance(value, float) and value.is_integer() and abs(value) < 1e15):
        return str(int(value))
    return f"{value:g}"


def _whole(amount: float, up: bool = False) -> int | float:
    """``amount`` rounded (``up``: ceiled) to an integer; inf stays inf (a product of large finite keys)."""
    if not math.isfinite(amount):
        return amount
    return math.ceil(amount) if up else round(amount)


def limit(name: str) -> int | float:
    """Current value of limit ``name``: ``$ROADTRACK_MAX_<NAME>`` if set, else its default."""
    lim = LIMITS[name]
    raw = os.environ.get(lim.env, "").strip()
    if not raw:
        return lim.default
    try:
        value = float(raw)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value > 0):
        raise ConfigError(lim.env, f"{raw!r} is not a limit; expected a positive number (default "
                          f"{_number(lim.default)} {lim.unit})")
    return int(value) if isinstance(lim.default, int) else value


def check(name: str, amount: float, key: str, what: str = "") -> None:
    """ConfigError at ``key`` when ``amount`` is above limit ``name`` (NaN is above every limit).

    ``what`` describes the amount when it is not the key's own value, e.g. ``"rays per scan"``.
    """
    bound = limit(name)
    if amount <= bound:
        return
    lim = LIMITS[name]
    shown = f"{_number(amount)} {what or lim.unit}".rstrip()
    raise ConfigError(key, f"{shown} is above the limit {_number(bound)} {lim.unit} (raise it with {lim.env})")


def at_most(name: str) -> dict:
    """Field metadata (``testbed.config.strict.field(..., **at_most("speed_mps"))``): the value, or the largest
    number in a list value, must not exceed limit ``name``."""
    def bound(value: Any, path: str) -> None:
        values = value if isinstance(value, (tuple, list)) else (value,)
        numbers = [v for v in values if isinstance(v, (int, float)) and not isinstance(v, bool)]
        if numbers:
            check(name, max(numbers), path)
    return {"validate": bound, "limit": name}


def check_seed(value: Any, key: str) -> int:
    """``value`` if it is an integer in [0, 2**32 - 1] (numpy's seed range), else ConfigError at ``key``."""
    if isinstance(value, bool) or not isinstance(value, int):
        raise ConfigError(key, f"expected an integer seed in 0..{SEED_MAX}, got {value!r}")
    if not 0 <= value <= SEED_MAX:
        raise ConfigError(key, f"{value} is not a seed; allowed: 0..{SEED_MAX} (2**32 - 1, numpy's range)")
    return value


def seed_field() -> dict:
    """Field metadata: an integer seed in [0, 2**32 - 1]."""
    return {"check": (lambda v: 0 <= v <= SEED_MAX, f"in 0..{SEED_MAX} = 2**32 - 1, numpy's seed range")}


_NAME_OK = re.compile(r"[A-Za-z0-9._-]+")


def check_folder_name(name: str, key: str) -> str:
    """``name`` if it can be an output folder name (one path component), else ConfigError at ``key``.

    Allowed: 1-100 ASCII letters, digits, '.', '_' and '-', not starting with '-' and not '.' or '..'.
    """
    allowed = f"allowed: 1-{NAME_MAX} ASCII letters, digits, '.', '_' and '-', not starting with '-', not '.' or '..'"
    if not isinstance(name, str):
        raise ConfigError(key, f"expected a name, got {name!r}; {allowed}")
    shown = repr(name if len(name) <= 60 else name[:57] + "...")
    if name in ("", ".", ".."):
        why = "is empty" if name == "" else "is not a folder name"
    elif len(name) > NAME_MAX:
        why = f"is {len(name)} characters long"
    elif name.startswith("-"):
        why = "starts with '-' (it would read as an option)"
    elif any(c in name for c in "/\\"):
        why = "contains a path separator"
    elif any(ord(c) < 32 or ord(c) == 127 for c in name):
        why = "contains a control character"
    elif not _NAME_OK.fullmatch(name):
        bad = next(c for c in name if not _NAME_OK.fullmatch(c))
        why = f"contains {bad!r}"
    else:
        return name
    raise ConfigError(key, f"{shown} {why}; {allowed}")


def markdown_table() -> str:
    """The limits as a markdown table (name, default, variable, what it bounds, why that default)."""
    lines = ["| limit | default | raise with | bounds | why this default |", "|---|---|---|---|---|"]
    for lim in LIMITS.values():
        lines.append(f"| `{lim.name}` | {_number(lim.default)} {lim.unit} | `{lim.env}` | {lim.keys} | {lim.why} |")
    return "\n".join(lines) + "\n"



# ------------------------------------------------------------------ derived amounts of a parsed scenario
def check_frames(duration_s: float, rate_hz: float) -> None:
    """Frames of a run, ``round(duration_s * rate_hz) + 1``, against the ``frames`` limit (key duration_s)."""
    frames = _whole(duration_s * rate_hz) + 1
    check("frames", frames, "duration_s", f"frames ({_number(duration_s)} s at {_number(rate_hz)} Hz)")


def segments_length_m(road: Any) -> float:
    """Total length [m] of a road's segments (testbed/world/simulation.py build_network): the lanes of one
    carriageway, or both carriageways of a motorway."""
    if road.kind == "curved":
        return 2 * road.length_m + road.curve_radius_m * math.radians(abs(road.curve_angle_deg))
    if road.kind == "u_turn":
        return 2 * road.length_m + math.pi * 22.0  # highway-env's U-turn: radii 20 and 24 m
    return (2 if road.kind == "motorway" else 1) * road.length_m


def background_vehicles(scn: Any) -> tuple[int, str]:
    """Background vehicles at the start of a run (``traffic.count``, or the density times the traffic window
    times the lanes with traffic) and the key that sets it ("" when there is no traffic)."""
    t, road = scn.traffic, scn.road
    if t.count > 0:
        return t.count, "traffic.count"
    if t.density_per_km_lane <= 0:
        return 0, ""
    lanes = 2 if road.kind == "u_turn" else road.lanes
    n_lanes = len(t.lanes) if t.lanes is not None else lanes
    if road.kind == "motorway":
        n_lanes += len(t.opposite_lanes) if t.opposite_lanes is not None else lanes
    window_km = min(t.window_behind_m + t.window_ahead_m, segments_length_m(road)) / 1000.0
    return _whole(t.density_per_km_lane * window_km * n_lanes, up=True), "traffic.density_per_km_lane"


def check_vehicles(scn: Any) -> None:
    """Scripted plus background vehicles against the ``vehicles`` limit (an env's ``[env.config]`` is bounded
    by testbed/scenario/envcheck.py when it is loaded)."""
    if scn.env is not None:
        return
    scripted = 1 + len(scn.vehicles) + (scn.convoy.count if scn.convoy is not None else 0)
    background, key = background_vehicles(scn)
    if not key:
        key = "convoy.count" if scn.convoy is not None and scn.convoy.count > len(scn.vehicles) else "vehicles"
    check("vehicles", scripted + background, key, f"vehicles ({scripted} scripted + {background} background)")


BARRIER_PITCH_M = 4.0  # testbed/world/roadside.py BARRIER_SEGMENT length: one guard-rail box per 4 m of edge


def check_roadside(scn: Any) -> None:
    """Expected roadside boxes along every road edge (two per segment) against ``roadside_objects``."""
    if scn.env is not None:
        return
    rs = scn.roadside
    edges_km = 2 * segments_length_m(scn.road) / 1000.0
    per_km = {"barriers": 1000.0 / BARRIER_PITCH_M if rs.barriers else 0.0,
              "post_spacing_m": 1000.0 / max(round(rs.post_spacing_m), 1) if rs.post_spacing_m > 0 else 0.0,
              "trees_per_km": 2.0 * rs.trees_per_km,  # trunk and crown
              "bushes_per_km": rs.bushes_per_km, "signs_per_km": rs.signs_per_km}
    total = edges_km * sum(per_km.values())
    key = max(per_km, key=lambda k: per_km[k])
    check("roadside_objects", _whole(total), f"roadside.{key}",
          f"objects expected along {edges_km:g} km of road edges")


def check_sensor(sensor: Any) -> None:
    """LiDAR pattern, ranges and added clutter of ``[sensor]`` against their limits."""
    lidar, clutter = sensor.lidar, sensor.clutter
    check("lidar_beams", lidar.n_beams, "sensor.lidar.n_beams")
    azimuths = 360.0 / lidar.azimuth_step_deg
    azimuths = math.floor(azimuths + 1e-9) if math.isfinite(azimuths) else math.inf
    check("lidar_rays", lidar.n_beams * azimuths, "sensor.lidar.azimuth_step_deg",
          f"rays per scan ({lidar.n_beams} beams x {_number(azimuths)} azimuths)")
    for key in ("max_range_m", "ground_half_size_m", "range_noise_std_m"):
        check("lidar_range_m", getattr(lidar, key), f"sensor.lidar.{key}")
    check("offset_m", lidar.mount_height_m, "sensor.lidar.mount_height_m")
    expected = clutter.density_per_m2 * math.pi * clutter.radius_m * clutter.radius_m
    check("clutter_points", _whole(expected), "sensor.clutter.density_per_m2",
          "points expected per frame (density_per_m2 x pi x radius_m^2)")
    check_perception(sensor.perception, lidar.max_range_m)


def check_perception(cfg: Any, max_range_m: float) -> None:
    """Grid sizes over the sensor's reach, RANSAC iterations and box-fit heading grids of ``cfg``."""
    from roadtrack.sensors.grid import MAX_CELLS

    reach = 2.0 * max_range_m
    grids = []
    if cfg.cluster.method == "grid":
        grids.append(("sensor.perception.cluster.cell_m", cfg.cluster.cell_m))
    if cfg.ground.method in ("grid", "road_plane"):
        grids.append(("sensor.perception.ground.cell_m", cfg.ground.cell_m))
    for key, cell in grids:
        side = reach / cell + 2.0
        cells = side * side  # inf, not OverflowError, for a tiny cell
        if cells > MAX_CELLS:
            least = reach / (math.sqrt(MAX_CELLS) - 2.0)
            raise ConfigError(key, f"{cell:g} m cells over the sensor's {reach:g} m reach (2 x max_range_m) make "
                              f"{cells:.3g} grid cells; allowed: at most {MAX_CELLS} (cell_m >= {least:.3g} m, or a "
                              "shorter sensor.lidar.max_range_m)")
    foot = cfg.ground.foot_cell_m
    if foot > 0 and reach / foot >= 2.0**31:
        raise ConfigError("sensor.perception.ground.foot_cell_m", f"{foot:g} m cells over the sensor's {reach:g} m "
                          f"reach overflow the cell keys; allowed: 0 (off) or >= {reach / 2.0**31:.3g} m")
    check("ransac_iterations", cfg.ground.ransac_iterations, "sensor.perception.ground.ransac_iterations")
    for key in ("step_deg", "coarse_step_deg"):
        check("box_headings", 90.0 / getattr(cfg.boxfit, key), f"sensor.perception.boxfit.{key}",
              f"headings (90 / {key})")


def check_scenario(scn: Any) -> None:
    """Every derived amount of a parsed scenario against its limit (the plain keys are bounded by their
    field metadata, :func:`at_most`)."""
    check_vehicles(scn)
    check_roadside(scn)
    check_sensor(scn.sensor)


# ------------------------------------------------------------------ campaigns
def check_campaign_size(seeds: int, n_scenarios: int, n_trackers: int, grid_sizes: dict[str, int]) -> int:
    """Runs of a campaign (scenarios x trackers x grid points x seeds) against ``campaign_seeds`` and
    ``campaign_runs``, before anything is built; returns the number of runs. ``grid_sizes``: grid key ->
    number of values. A refusal names the largest factor's key."""
    check("campaign_seeds", seeds, "seeds")
    factors = {"scenarios": n_scenarios, "trackers": n_trackers,
               **{f'grid."{k}"': n for k, n in grid_sizes.items()}, "seeds": seeds}
    runs = math.prod(factors.values())
    key = max(factors, key=lambda k: factors[k])
    text = " x ".join(f"{n} {k}" if not k.startswith("grid") else f"{n} values of {k}" for k, n in factors.items())
    check("campaign_runs", runs, key, f"runs ({text})")
    return runs
