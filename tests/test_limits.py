"""Resource limits, seeds, folder names, unreadable files and overlapping vehicles: every bad input to the
scenario and campaign loaders is refused up front with ONE line naming the file or key (testbed/config/limits.py,
docs/limits.md)."""
from __future__ import annotations

import contextlib
import io
import os
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from roadtrack.testbed.config import limits  # noqa: E402
from roadtrack.testbed.campaign.spec import load_campaign, plan, run_seed  # noqa: E402
from roadtrack.testbed.config.strict import ConfigError  # noqa: E402
from roadtrack.testbed.config.limits import LIMITS, SEED_MAX, check_folder_name  # noqa: E402
from roadtrack.testbed.scenario.spec import LANE_WIDTH_M, list_scenarios, load_scenario  # noqa: E402

CAMPAIGNS = sorted((REPO / "campaigns").glob("*.toml"))


def refused(func, *args, **kwargs) -> str:
    """The one-line message of the ConfigError ``func`` raises."""
    with pytest.raises(ConfigError) as info:
        func(*args, **kwargs)
    text = str(info.value)
    assert "\n" not in text and text.strip() == text and text, repr(text)
    return text


def campaign_file(tmp_path: Path, text: str, name: str = "c.toml") -> Path:
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


BASE = 'scenarios = ["cut_in_out"]\ntrackers = ["jpda-kf"]\n'


# ------------------------------------------------------------------ shipped files pass with margin
@pytest.fixture
def tight_limits(monkeypatch):
    """Every limit divided by 2.5: the shipped files must still load (the margin docs/limits.md promises)."""
    for lim in LIMITS.values():
        monkeypatch.setenv(lim.env, str(lim.default / 2.5))


@pytest.mark.parametrize("name", list_scenarios())
def test_every_shipped_scenario_loads_with_margin(tight_limits, name):
    assert load_scenario(name).name == name


@pytest.mark.parametrize("path", CAMPAIGNS, ids=lambda p: p.stem)
def test_every_shipped_campaign_loads_with_margin_and_its_run_seeds_are_uint32(tight_limits, path):
    campaign = load_campaign(path)
    runs = plan(campaign)
    assert len(runs) == campaign.n_runs <= limits.limit("campaign_runs")
    assert all(0 <= r.seed <= SEED_MAX for r in runs)


def test_docs_limits_md_lists_every_limit():
    assert limits.markdown_table() in (REPO / "docs" / "limits.md").read_text(), \
        "docs/limits.md is stale: paste testbed.config.limits.markdown_table() into it"


def test_a_limit_variable_that_is_not_a_positive_number_is_refused(monkeypatch):
    for raw in ("abc", "-1", "0", "nan", "inf"):
        monkeypatch.setenv("ROADTRACK_MAX_DURATION_S", raw)
        text = refused(load_scenario, "convoy")
        assert text.startswith("ROADTRACK_MAX_DURATION_S: ") and "positive number" in text


# ------------------------------------------------------------------ each bound: refused, and raised by its variable
# (overrides on `convoy`, key named in the message, limit, value of the variable that lets it load)
BOUNDS = [
    ({"duration_s": 1e9}, "duration_s", "duration_s", None),
    ({"duration_s": 4000.0}, "duration_s", "duration_s", 5000),
    ({"duration_s": 1e308}, "duration_s", "duration_s", None),
    ({"duration_s": 3000.0, "rate_hz": 20.0}, "duration_s", "frames", 1e5),
    ({"rate_hz": 1e9}, "rate_hz", "rate_hz", None),
    ({"rate_hz": 200.0}, "rate_hz", "rate_hz", 300),
    ({"physics_substeps": 10**9}, "physics_substeps", "physics_substeps", 2e9),
    ({"convoy.count": 10**9}, "convoy.count", "vehicles", None),
    ({"convoy.count": 600, "road.length_m": 20000.0, "convoy.front_position_m": 19000.0}, "convoy.count",
     "vehicles", 1000),
    ({"traffic.count": 600}, "traffic.count", "vehicles", 1000),
    ({"traffic.density_per_km_lane": 300.0}, "traffic.density_per_km_lane", "vehicles", 1000),
    ({"road.length_m": 1e12}, "road.length_m", "road_length_m", None),
    ({"road.length_m": 200000.0}, "road.length_m", "road_length_m", 3e5),
    ({"road.kind": "curved", "road.curve_radius_m": 2e5}, "road.curve_radius_m", "road_length_m", 3e5),
    ({"convoy.gap_m": 1e308}, "convoy.gap_m", "road_length_m", None),
    ({"traffic.window_ahead_m": 1e6}, "traffic.window_ahead_m", "road_length_m", 2e6),
    ({"roadside.barrier_offset_m": 2000.0}, "roadside.barrier_offset_m", "offset_m", 3000),
    ({"sensor.lidar.mount_height_m": 1e300}, "sensor.lidar.mount_height_m", "offset_m", None),
    ({"ego.speed_mps": 1e308}, "ego.speed_mps", "speed_mps", None),
    ({"ego.speed_mps": 150.0}, "ego.speed_mps", "speed_mps", 200),
    ({"traffic.speed_mps": [20.0, 1e9]}, "traffic.speed_mps", "speed_mps", None),
    ({"ego.length_m": 60.0}, "ego.length_m", "vehicle_size_m", 100),
    ({"roadside.trees_per_km": 1e9}, "roadside.trees_per_km", "roadside_objects", None),
    ({"roadside.trees_per_km": 1e308}, "roadside.trees_per_km", "roadside_objects", None),
    ({"traffic.density_per_km_lane": 1e308}, "traffic.density_per_km_lane", "vehicles", None),
    ({"sensor.clutter.density_per_m2": 1e308}, "sensor.clutter.density_per_m2", "clutter_points", None),
    ({"roadside.trees_per_km": 1e5}, "roadside.trees_per_km", "roadside_objects", 1e6),
    ({"roadside.post_spacing_m": 1e-9, "road.length_m": 100000.0}, "roadside.post_spacing_m", "roadside_objects",
     3e5),
    ({"sensor.lidar.n_beams": 100000}, "sensor.lidar.n_beams", "lidar_beams", None),
    ({"sensor.lidar.n_beams": 600, "sensor.lidar.azimuth_step_deg": 2.0}, "sensor.lidar.n_beams", "lidar_beams",
     1000),
    ({"sensor.lidar.azimuth_step_deg": 1e-9}, "sensor.lidar.azimuth_step_deg", "lidar_rays", None),
    ({"sensor.lidar.azimuth_step_deg": 5e-324}, "sensor.lidar.azimuth_step_deg", "lidar_rays", None),
    ({"sensor.lidar.azimuth_step_deg": 0.01}, "sensor.lidar.azimuth_step_deg", "lidar_rays", 2e6),
    ({"sensor.lidar.max_range_m": 600.0, "sensor.perception.cluster.cell_m": 1.0}, "sensor.lidar.max_range_m",
     "lidar_range_m", 1000),
    ({"sensor.clutter.radius_m": 1e6}, "sensor.clutter.radius_m", "lidar_range_m", None),
    ({"scoring.match_distance_m": 1e308}, "scoring.match_distance_m", "lidar_range_m", None),
    ({"sensor.clutter.density_per_m2": 10.0}, "sensor.clutter.density_per_m2", "clutter_points", 1e6),
    ({"sensor.perception.ground.ransac_iterations": 10**9}, "sensor.perception.ground.ransac_iterations",
     "ransac_iterations", 2e9),
    ({"sensor.perception.boxfit.step_deg": 0.01}, "sensor.perception.boxfit.step_deg", "box_headings", 1e4),
    ({"ego.lane_changes": [{"at_s": 1e308, "lane": 1}]}, "ego.lane_changes[0].at_s", "duration_s", None),
]


@pytest.mark.parametrize("over, key, name, raised", BOUNDS, ids=[f"{b[1]}={list(b[0].values())[0]}" for b in BOUNDS])
def test_over_limit_values_are_refused_and_the_variable_raises_the_limit(monkeypatch, over, key, name, raised):
    lim = LIMITS[name]
    text = refused(load_scenario, "convoy", over)
    assert text.startswith(f"{key}: ") and "is above the limit" in text, text
    assert f"(raise it with {lim.env})" in text and lim.unit in text, text
    if raised is not None:
        monkeypatch.setenv(lim.env, str(raised))
        load_scenario("convoy", over)


def test_an_env_vehicle_count_is_refused_before_the_env_is_built(monkeypatch):
    over = {"env.id": "highway-v0", "env.config.vehicles_count": 10**9}
    assert refused(load_scenario, "merge", over) == ("env.config.vehicles_count: 1000000000 vehicles is above the "
                                                     "limit 500 vehicles (raise it with ROADTRACK_MAX_VEHICLES)")


def test_duration_message_is_the_documented_one():
    assert refused(load_scenario, "convoy", {"duration_s": 1e9}) == \
        "duration_s: 1000000000 s is above the limit 3600 s (raise it with ROADTRACK_MAX_DURATION_S)"


def test_a_lower_limit_refuses_the_shipped_file_by_size(monkeypatch):
    monkeypatch.setenv("ROADTRACK_MAX_FILE_BYTES", "100")
    text = refused(load_scenario, "convoy")
    assert text.startswith(str(REPO / "scenarios" / "convoy.toml") + ": ") and "ROADTRACK_MAX_FILE_BYTES" in text


@pytest.mark.parametrize("over, key", [
    ({"sensor.perception.cluster.cell_m": 0.01}, "sensor.perception.cluster.cell_m"),
    ({"sensor.perception.ground.cell_m": 0.01}, "sensor.perception.ground.cell_m"),
    ({"sensor.perception.ground.foot_cell_m": 1e-9}, "sensor.perception.ground.foot_cell_m"),
    ({"sensor.perception.cluster.cell_m": 1e-300}, "sensor.perception.cluster.cell_m"),
    ({"road.kind": "curved", "road.curve_radius_m": 4.0}, "road.curve_radius_m"),
    ({"duration_s": 10**400}, "duration_s"),
    ({"duration_s": float("nan")}, "duration_s"),
    ({"ego.position_m": float("inf")}, "ego.position_m"),
])
def test_impossible_geometry_and_numbers_are_refused(over, key):
    text = refused(load_scenario, "convoy", over)
    assert text.startswith(f"{key}: ") and "allowed" in text or "finite" in text, text


# ------------------------------------------------------------------ campaigns: sizes before the run list
def test_a_billion_seeds_is_refused_at_once(tmp_path):
    path = campaign_file(tmp_path, BASE + "seeds = 1000000000\n")
    text = refused(load_campaign, path)
    assert text == (f"{path}: seeds: 1000000000 seeds is above the limit 10000 seeds (raise it with "
                    "ROADTRACK_MAX_CAMPAIGN_SEEDS)")


def test_campaign_runs_are_counted_before_anything_is_built(tmp_path, monkeypatch):
    grid = "[grid]\nduration_s = [1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0, 10.0, 11.0, 12.0]\n"
    path = campaign_file(tmp_path, BASE + "seeds = 9000\n" + grid)
    text = refused(load_campaign, path)
    assert "seeds: 108000 runs (1 scenarios x 1 trackers x 12 values of grid.\"duration_s\" x 9000 seeds)" in text
    assert "ROADTRACK_MAX_CAMPAIGN_RUNS" in text
    monkeypatch.setenv("ROADTRACK_MAX_CAMPAIGN_RUNS", "200000")
    assert load_campaign(path).n_runs == 108000


def test_campaign_seeds_limit_is_raised_by_its_variable(tmp_path, monkeypatch):
    path = campaign_file(tmp_path, BASE + "seeds = 20000\n")
    assert "ROADTRACK_MAX_CAMPAIGN_SEEDS" in refused(load_campaign, path)
    monkeypatch.setenv("ROADTRACK_MAX_CAMPAIGN_SEEDS", "30000")
    assert load_campaign(path).seeds == 20000


def test_campaign_overrides_are_bounded_like_the_scenario(tmp_path):
    path = campaign_file(tmp_path, BASE + "seeds = 2\n[overrides]\nduration_s = 1e308\n")
    text = refused(load_campaign, path)
    assert text.startswith(f'{path}: overrides."duration_s": duration_s: 1e+308 s is above the limit 3600 s')


# ------------------------------------------------------------------ seeds
@pytest.mark.parametrize("seed, ok", [(0, True), (SEED_MAX, True), (2**32, False), (-1, False), (2**64, False)])
def test_scenario_and_campaign_seeds_are_numpy_uint32(tmp_path, seed, ok):
    path = campaign_file(tmp_path, BASE + f"seeds = 2\nbase_seed = {seed}\n")
    if ok:
        assert load_scenario("convoy", {"seed": seed}).seed == seed
        assert load_campaign(path).base_seed == seed
        return
    assert refused(load_scenario, "convoy", {"seed": seed}).startswith(f"seed: {seed} is not allowed; must be in "
                                                                       f"0..{SEED_MAX}")
    assert refused(load_campaign, path).startswith(f"{path}: base_seed: {seed} is not allowed")


def test_derived_run_seeds_stay_in_range_at_the_extremes():
    for base in (0, SEED_MAX):
        for index in (0, 1, 9999):
            assert 0 <= run_seed(base, "a" * 100, index) <= SEED_MAX


# ------------------------------------------------------------------ output folder names
BAD_NAMES = ["", ".", "..", "../../escaped", "a/b", "a\\b", "-rf", "a\x00b", "tab\there", "new\nline",
             "a" * 101, "caf\u00e9", "a b", "x:y", "*"]


@pytest.mark.parametrize("name", BAD_NAMES, ids=repr)
def test_bad_folder_names_are_refused_by_every_loader(tmp_path, name):
    text = refused(check_folder_name, name, "name")
    assert text.startswith("name: ") and "allowed: 1-100 ASCII letters, digits, '.', '_' and '-'" in text
    assert refused(load_scenario, "convoy", {"name": name}).startswith("name: ")
    if name == "":
        return  # a campaign's name = "" means the default, the file name
    esc = name.replace("\\", "\\\\").replace('"', '\\"').replace("\n", "\\n").replace("\t", "\\t")
    esc = esc.replace("\x00", "\\u0000")
    path = campaign_file(tmp_path, f'name = "{esc}"\n' + BASE + "seeds = 1\n")
    assert refused(load_campaign, path).startswith(f"{path}: name: ")


@pytest.mark.parametrize("name", ["a", "convoy", "run-2.v3_final", "A" * 100, "x.toml", ".hidden"])
def test_good_folder_names_pass(name):
    assert check_folder_name(name, "name") == name
    assert load_scenario("convoy", {"name": name}).name == name


def test_a_campaign_named_after_a_bad_file_name_says_to_set_name(tmp_path):
    path = campaign_file(tmp_path, BASE + "seeds = 1\n", "my sweep.toml")
    text = refused(load_campaign, path)
    assert "'my sweep' contains ' '" in text and 'set name = "..." in the file' in text


# ------------------------------------------------------------------ files that cannot be read as UTF-8 TOML
SHIPPED = (REPO / "scenarios" / "convoy.toml").read_text(encoding="utf-8")
FILES = {
    "latin1": ('name = "caf\u00e9"\n'.encode("latin-1"), "not UTF-8 text (byte 0xe9 on line 1)"),
    "utf16": (SHIPPED.encode("utf-16"), "is UTF-16 text; expected UTF-8"),
    "utf16be": (b"\xfe\xff" + SHIPPED.encode("utf-16-be"), "is UTF-16 text; expected UTF-8"),
    "utf32": (SHIPPED.encode("utf-32"), "is UTF-32 text; expected UTF-8"),
    "binary": (bytes(range(256)) * 4, "contains NUL bytes (a binary file?)"),
    "nul": (SHIPPED.encode() + b"\x00\n", "contains NUL bytes"),
    "invalid": (b'name = "\xc3\x28"\n', "not UTF-8 text (byte 0xc3 on line 1)"),
    "deep": (b"a = " + b"[" * 5000 + b"]" * 5000, "nested too deeply"),
    "bad_toml": (b'name = "x\n', "not valid TOML"),
}


@pytest.mark.parametrize("kind", sorted(FILES))
def test_unreadable_scenario_and_campaign_files_give_one_line(tmp_path, kind):
    raw, expected = FILES[kind]
    path = tmp_path / f"{kind}.toml"
    path.write_bytes(raw)
    for loader in (load_scenario, load_campaign):
        text = refused(loader, path)
        assert text.startswith(f"{path}: ") and expected in text, text


def test_a_utf8_byte_order_mark_is_accepted(tmp_path):
    path = tmp_path / "bom.toml"
    path.write_bytes(b"\xef\xbb\xbf" + SHIPPED.encode("utf-8"))
    assert load_scenario(path).name == "convoy"


def test_a_campaign_entry_naming_an_unreadable_scenario_is_reported_at_the_entry(tmp_path):
    (tmp_path / "latin.toml").write_bytes('name = "caf\u00e9"\n'.encode("latin-1"))
    path = campaign_file(tmp_path, 'scenarios = ["latin.toml"]\ntrackers = ["jpda-kf"]\nseeds = 1\n')
    text = refused(load_campaign, path)
    assert text.startswith(f"{path}: scenarios[0]: ") and "not UTF-8 text" in text


def test_unreadable_files_and_bad_paths_give_one_line(tmp_path, monkeypatch):
    (tmp_path / "folder.toml").mkdir()
    cases = [(tmp_path / "folder.toml", "is a directory; expected a scenario file (.toml)"),
             (tmp_path, "is a directory"),
             ("a\x00b.toml", "a path cannot contain a NUL character"),
             ("x" * 5000 + ".toml", "file name too long"),
             (tmp_path / ("y" * 300) / "z.toml", "file name too long"),
             ("/dev/null", "not a regular file"),
             (tmp_path / "missing.toml", "no such scenario file (shipped: convoy,")]
    for path, expected in cases:
        text = refused(load_scenario, path)
        assert expected in text and len(text) < 400, text
    text = refused(load_campaign, tmp_path / "folder.toml")
    assert "is a directory; expected a campaign file (.toml)" in text
    locked = tmp_path / "locked.toml"
    locked.write_text(SHIPPED)

    def denied(self):
        raise PermissionError(13, os.strerror(13), str(self))

    monkeypatch.setattr(Path, "read_bytes", denied)
    assert refused(load_scenario, locked) == f"{locked}: cannot read it (permission denied)"


@pytest.mark.skipif(os.geteuid() == 0, reason="root reads any file")
def test_a_file_without_read_permission_gives_one_line(tmp_path):
    path = tmp_path / "locked.toml"
    path.write_text(SHIPPED)
    path.chmod(0)
    try:
        assert refused(load_scenario, path) == f"{path}: cannot read it (permission denied)"
    finally:
        path.chmod(0o644)


# ------------------------------------------------------------------ overlapping vehicles
def test_lane_width_matches_the_simulation():
    from roadtrack.testbed.world.simulation import LANE_WIDTH

    assert LANE_WIDTH_M == LANE_WIDTH


OVERLAPS = [
    # a car on the sensor car: the convoy (lane 1) moved onto the ego's lane and position
    ({"ego.lane": 1, "ego.position_m": 150.0}, "convoy.front_position_m", "convoy[1] (lane 1, position_m 150) "
     "overlaps ego (lane 1, position_m 150)"),
    # two cars at the same place
    ({"vehicles": [{"position_m": 300.0}, {"position_m": 300.0}]}, "vehicles[1].position_m",
     "vehicles[1] (lane 0, position_m 300) overlaps vehicles[0] (lane 0, position_m 300)"),
    # 3 m apart in one lane: 5 m cars overlap
    ({"vehicles": [{"position_m": 300.0}, {"position_m": 303.0}]}, "vehicles[1].position_m",
     "allowed: centres at least 5 m apart"),
    # wide vehicles in neighbouring lanes
    ({"vehicles": [{"position_m": 300.0, "width_m": 5.0}, {"lane": 1, "position_m": 300.0, "width_m": 5.0}]},
     "vehicles[1].position_m", "vehicles[1] (lane 1, position_m 300) overlaps vehicles[0] (lane 0"),
    # scripted jitter could push the convoy cars (10 m gaps) into each other
    ({"traffic.position_jitter_m": 6.0}, "convoy.gap_m", "half their lengths + 2 x traffic.position_jitter_m"),
]


@pytest.mark.parametrize("over, key, expected", OVERLAPS)
def test_vehicles_overlapping_at_the_start_are_refused(over, key, expected):
    text = refused(load_scenario, "convoy", over)
    assert text.startswith(f"{key}: ") and expected in text and "crash at frame 0" in text, text


@pytest.mark.parametrize("over", [
    {"vehicles": [{"position_m": 300.0}, {"position_m": 305.0}]},  # bumper to bumper
    {"vehicles": [{"position_m": 300.0}, {"lane": 1, "position_m": 300.0}]},  # side by side
    {"traffic.position_jitter_m": 4.0},  # convoy gaps 10 m: 2 x 4 m of jitter still leaves 2 m
])
def test_vehicles_that_only_touch_or_drive_side_by_side_are_accepted(over):
    load_scenario("convoy", over)


# ------------------------------------------------------------------ through the command line: exit 2, one line
def cli(args: list[str]) -> tuple[int, list[str]]:
    from roadtrack.testbed.cli.main import main

    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        try:
            code = main(args)
        except SystemExit as exc:
            code = exc.code
    return code, [ln for ln in err.getvalue().splitlines() if ln.strip()]


def test_cli_refuses_bad_scenarios_with_exit_2_and_one_line(tmp_path):
    latin = tmp_path / "latin.toml"
    latin.write_bytes('name = "caf\u00e9"\n'.encode("latin-1"))
    check_cli([(["run", str(latin), "--out", str(tmp_path / "r1")], "not UTF-8 text"),
             (["run", "convoy", "--seed", str(2**32), "--out", str(tmp_path / "r2")], "seed: 4294967296"),
             (["run", "convoy", "--set", "duration_s=1e308", "--out", str(tmp_path / "r3")],
              "ROADTRACK_MAX_DURATION_S"),
             (["run", "convoy", "--set", "convoy.count=1000000000", "--out", str(tmp_path / "r4")], "convoy.count"),
             (["run", "convoy", "--set", "name='../../escaped'", "--out", str(tmp_path / "r5")], "path separator"),
             (["run", str(tmp_path), "--out", str(tmp_path / "r6")], "is a directory")])


def test_cli_refuses_bad_campaigns_with_exit_2_and_one_line(tmp_path):
    big = campaign_file(tmp_path, BASE + "seeds = 1000000000\n")
    runs = campaign_file(tmp_path, BASE + "seeds = 9000\n[grid]\nduration_s = " + str([1.0 * i for i in range(1, 13)])
                         + "\n", "runs.toml")
    utf16 = tmp_path / "utf16.toml"
    utf16.write_bytes((BASE + "seeds = 1\n").encode("utf-16"))
    check_cli([(["campaign", "run", str(big), "--out", str(tmp_path / "c1")], "ROADTRACK_MAX_CAMPAIGN_SEEDS"),
               (["campaign", "run", str(runs), "--out", str(tmp_path / "c2")], "ROADTRACK_MAX_CAMPAIGN_RUNS"),
               (["campaign", "run", str(utf16), "--out", str(tmp_path / "c3")], "is UTF-16 text")])


def check_cli(cases: list[tuple[list[str], str]]) -> None:
    for args, expected in cases:
        code, lines = cli(args)
        assert code == 2 and len(lines) == 1 and lines[0].startswith("error: ") and expected in lines[0], \
            (args, code, lines)
        assert not Path(args[-1]).exists()
