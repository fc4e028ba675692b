"""Sensors as plug-ins (issue 32.2): random streams by name, the sensor registry, a toy sensor added from a
temporary package in 1 module + 1 registry line (an entry point), sensed in a real short run and through the
sensing cache, which refuses in one line the data it cannot store."""
from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path
import warnings

import numpy as np
import pytest

from roadtrack import testbed
from roadtrack.testbed.common import streams
from roadtrack.testbed.config import ConfigError
from roadtrack.testbed.sensing import SENSORS, Sensor, rng_streams, scenario_sensors, sense, sensor_registry
from roadtrack.testbed.sensing.cache import SensingCache
from roadtrack.testbed.world import load_scenario
from roadtrack.trackers.plugins import PluginWarning

REPO = Path(__file__).resolve().parent.parent
BEACON = '''
"""A toy sensor: a beacon receiver that reports each car within 40 m of the ego as its position plus noise."""
import numpy as np
from roadtrack.testbed.sensing import Sensor

RANGE_M, SIGMA_M = 40.0, 0.5


def in_view(truth):
    return np.hypot(*(truth.xy - truth.xy[0]).T) <= RANGE_M


def sense(ctx, truth, rngs, stream="sensor.beacon"):
    noise = rngs[stream].normal(0.0, SIGMA_M, size=(len(truth.ids), 2))  # for every car, seen or not
    seen = in_view(truth)
    seen[0] = False  # not the ego
    return {"id": truth.ids[seen], "z": truth.xy[seen] + noise[seen]}


def visibility(ctx, truth, data):
    return np.isin(truth.ids, data["id"]).astype(np.int64), in_view(truth)


SENSOR = Sensor("beacon", sense, visibility, doc="toy beacon receiver")


def measurements(ctx, truth, data):
    from roadtrack.testbed.sensing import Measurements
    from roadtrack.trackers.models import PositionMeasurement

    return Measurements(data["z"], PositionMeasurement(SIGMA_M), None, 0.95, 1e-4)


TRACKED = Sensor("tracked", lambda ctx, truth, rngs: sense(ctx, truth, rngs, "sensor.beacon2"), visibility,
                 streams=("sensor.beacon2",), measurements=measurements,
                 doc="the beacon, its detections given to trackers")
LISTY = Sensor("listy", lambda ctx, truth, rngs: [1.0, 2.0], lambda ctx, truth, data: (None, None))
THIEF = Sensor("thief", sense, visibility, streams=("lidar",))
'''


@pytest.fixture
def beacon(tmp_path, monkeypatch):
    """The toy package: one module and its entry points (the registry lines), importable for this test only."""
    (tmp_path / "toy_beacon.py").write_text(textwrap.dedent(BEACON))
    info = tmp_path / "toy_beacon-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: toy-beacon\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text("[roadtrack.sensors]\nbeacon = toy_beacon:SENSOR\n"
                                           "listy = toy_beacon:LISTY\nthief = toy_beacon:THIEF\n"
                                           "tracked = toy_beacon:TRACKED\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    sensor_registry.cache_clear()
    yield
    sys.modules.pop("toy_beacon", None)
    sensor_registry.cache_clear()


def test_existing_streams_are_unchanged_and_a_new_name_is_a_stream_of_its_own():
    seed = 2024
    children = np.random.SeedSequence(seed).spawn(4)
    for i, name in enumerate(("roadside", "lidar", "clutter")):
        np.testing.assert_array_equal(streams.generator(seed, name).random(8),
                                      np.random.default_rng(children[i]).random(8))
        np.testing.assert_array_equal(rng_streams(seed)[name].random(8), np.random.default_rng(children[i]).random(8))
    for name, child in zip(("traffic.jitter", "traffic.background"), children[3].spawn(2)):
        np.testing.assert_array_equal(streams.generator(seed, name).random(8), np.random.default_rng(child).random(8))
    legacy = {n: streams.generator(seed, n).random(8) for n in streams.LEGACY}
    for new in ("sensor.beacon", "sensor.radar", "radar", "traffic.trucks"):
        draws = streams.generator(seed, new).random(8)
        assert streams.spawn_key(new) not in streams.LEGACY.values()
        assert all(np.abs(draws - d).max() > 1e-3 for d in legacy.values()), new  # shares no stream
        np.testing.assert_array_equal(rng_streams(seed)[new].random(8), draws)  # made on first use, by name


def test_two_names_with_the_same_crc32_are_refused_in_one_line():
    # "plumless" and "buckeroo" have the same crc32 (a known pair)
    assert streams.spawn_key("plumless") == streams.spawn_key("buckeroo")
    with pytest.raises(ValueError, match=r"^random streams 'plumless' and 'buckeroo' would be the same") as err:
        streams.check_distinct(["lidar", "plumless", "buckeroo"])
    assert "\n" not in str(err.value)
    with pytest.raises(ValueError, match="non-empty string"):
        streams.spawn_key("")


def test_every_registered_sensor_keeps_the_contract():
    reg = sensor_registry()
    assert "lidar" in reg and reg["lidar"] is SENSORS["lidar"]
    names = [s for sensor in reg.values() for s in sensor.streams]
    assert len(names) == len(set(names))
    streams.check_distinct(names)
    for name, sensor in reg.items():
        assert isinstance(sensor, Sensor) and sensor.name == name and callable(sensor.sense)
        assert callable(sensor.visibility) and (sensor.pd is None or callable(sensor.pd))
    assert Sensor("x", print, print).streams == ("sensor.x",)


def test_an_unknown_or_repeated_sensor_is_one_line_naming_its_key():
    for extra, match in ((["nope"], r"sensor\.extra\[0\]: 'nope' is not a sensor; allowed: "),
                         (["lidar"], r"sensor\.extra\[0\]: 'lidar' is always on")):
        scn = load_scenario("cut_in_out", {"duration_s": 0.2, "sensor.extra": extra})
        with pytest.raises(ConfigError, match=match) as err:
            next(iter(sense(scn)))
        assert "\n" not in str(err.value)


def test_the_cli_refuses_an_unknown_sensor_before_writing_anything(tmp_path):
    out = tmp_path / "run"
    env = {**os.environ, "PYTHONPATH": str(REPO), "RERUN_ANALYTICS": "0"}
    res = subprocess.run([sys.executable, "-m", "roadtrack.testbed.cli.main", "run", "cut_in_out", "--set", "duration_s=0.2",
                          "--set", 'sensor.extra=["nope"]', "--no-record", "--quiet", "--out", str(out)],
                         capture_output=True, text=True, env=env, cwd=tmp_path, timeout=300)
    assert res.returncode == 2 and not out.exists()
    assert res.stderr.strip().splitlines() == [
        f"error: sensor.extra[0]: 'nope' is not a sensor; allowed: radar (nothing was written ({out} is "
        "unchanged))"]
    with pytest.raises(ConfigError, match=r"^sensor\.extra\[0\]: 'nope' is not a sensor"):
        testbed.sense(load_scenario("cut_in_out", {"duration_s": 0.2, "sensor.extra": ["nope"]}))  # at the call


def test_a_toy_sensor_from_a_temporary_package_is_sensed_on_its_own_stream(beacon):
    with pytest.warns(PluginWarning, match=r"'thief'.*random stream 'lidar' belongs to 'lidar'"):
        reg = sensor_registry()
    assert "beacon" in reg and "thief" not in reg and reg["beacon"].streams == ("sensor.beacon",)
    base = load_scenario("cut_in_out", {"duration_s": 0.5})
    scn = load_scenario("cut_in_out", {"duration_s": 0.5, "sensor.extra": ["beacon"]})
    assert [s.name for s in scenario_sensors(scn)] == ["lidar", "beacon"]
    plain, with_beacon = list(sense(base)), list(sense(scn))
    assert len(with_beacon) == len(plain) == 6
    rng = streams.generator(scn.seed, "sensor.beacon")
    seen_total = 0
    for a, b in zip(plain, with_beacon):
        # the LiDAR draws exactly as without the beacon: its streams are untouched
        np.testing.assert_array_equal(a.detections.z, b.detections.z)
        np.testing.assert_array_equal(a.scan.ranges, b.scan.ranges)
        assert a.others == {} and set(b.others) == {"beacon"}
        noise = rng.normal(0.0, 0.5, size=(len(b.truth.ids), 2))
        d = np.hypot(*(b.truth.xy - b.truth.xy[0]).T)
        seen = (d <= 40.0) & (np.arange(len(d)) > 0)
        got = b.others["beacon"]
        np.testing.assert_array_equal(got.data["id"], b.truth.ids[seen])
        np.testing.assert_allclose(got.data["z"], b.truth.xy[seen] + noise[seen], rtol=0, atol=1e-12)
        np.testing.assert_array_equal(got.visibility[0], seen.astype(np.int64))
        assert got.pd is None
        seen_total += int(seen.sum())
    assert seen_total >= 6  # cut_in_out has cars within 40 m of the ego from the start


def test_the_cache_stores_the_toy_sensor_and_refuses_data_it_cannot_store(beacon, tmp_path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", PluginWarning)
        sensor_registry()
    scn = load_scenario("cut_in_out", {"duration_s": 0.3, "sensor.extra": ["beacon"]})
    cache = SensingCache(tmp_path / "cache")
    live = list(cache.frames(scn))
    assert cache.has(scn) and (cache.entry(scn) / "others-beacon.parquet").is_file()
    cached = list(cache.frames(scn))
    assert len(cached) == len(live) == 4
    for a, b in zip(live, cached):
        x, y = a.others["beacon"], b.others["beacon"]
        for col in ("id", "z"):
            assert x.data[col].dtype == y.data[col].dtype
            np.testing.assert_array_equal(x.data[col], y.data[col])
        for u, v in zip(x.visibility, y.visibility):
            np.testing.assert_array_equal(u, v)
    module = tmp_path / "toy_beacon.py"
    module.write_text(module.read_text() + "# edited\n")  # the plug-in's code is part of the key: no stale entry
    assert not cache.has(scn)
    bad = load_scenario("cut_in_out", {"duration_s": 0.3, "sensor.extra": ["listy"]})
    with pytest.raises(ConfigError, match=r"^sensing_cache: cannot store the data of sensor 'listy': it is a list, "
                                          r"not a dict") as err:
        list(cache.frames(bad))
    assert "\n" not in str(err.value) and not cache.has(bad)


def test_a_toy_sensor_with_measurements_is_tracked_and_written_without_other_changes(beacon, tmp_path):
    """1 module + 1 registry line (an entry point) is all a sensor a tracker takes needs: its detections, with the
    model they carry, update the LiDAR's tracks and are written to detections-<name>.parquet."""
    import pandas as pd

    from roadtrack.testbed.pipeline.run import run_scenario

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", PluginWarning)
        sensor_registry()
    base = run_scenario(load_scenario("cut_in_out", {"duration_s": 2.0}), out_dir=tmp_path / "a",
                                record=False)
    scn = load_scenario("cut_in_out", {"duration_s": 2.0, "sensor.extra": ["tracked"],
                                       "tracker.sensors": ["lidar", "tracked"]})
    fused = run_scenario(scn, out_dir=tmp_path / "b", record=False)
    got = pd.read_parquet(tmp_path / "b" / "detections-tracked.parquet")
    assert len(got) > 0 and got.frame.nunique() == 21
    np.testing.assert_allclose(np.stack(got.z), got[["x", "y"]].to_numpy())  # a position model: z is x, y
    a, b = pd.read_parquet(tmp_path / "a" / "tracks.parquet"), pd.read_parquet(tmp_path / "b" / "tracks.parquet")
    assert len(a) == len(b) and not np.allclose(a[["x", "y"]], b[["x", "y"]])  # the beacon moved the estimates
    assert fused.scores.cars_tracked == base.scores.cars_tracked
