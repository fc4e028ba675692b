"""Sense once, track many from Python, at scale (issue 31 point 7): light frames (no point cloud, a sparse range
image behind the P_D) give a tracker exactly what full frames give; ``sense(..., sensing_cache=DIR)`` senses into
the cache ``run`` uses and streams from it; ``score_frames`` scores what ``track`` yields as ``run`` does; bad
arguments are one-line errors at the call."""
from __future__ import annotations

import math

import numpy as np
import pytest

from roadtrack import testbed
from roadtrack import trackers
from roadtrack.testbed.config import ConfigError
from roadtrack.testbed.sensing.cache import SensingCache
from roadtrack.testbed.sensing.light import LightPD, PackedRanges

SHORT = {"duration_s": 2.0}


@pytest.fixture(scope="module")
def scn():
    return testbed.load_scenario("cut_in_out", SHORT)


@pytest.fixture(scope="module")
def full(scn):
    return list(testbed.sense(scn))


def _rows(pairs):
    return [(sf.index, ts.ids.tolist(), ts.xy.copy(), ts.status.tolist()) for sf, ts in pairs]


def _same(a, b) -> None:
    assert len(a) == len(b) > 0
    for (fa, ia, xa, sa), (fb, ib, xb, sb) in zip(a, b):
        assert fa == fb and ia == ib and sa == sb
        np.testing.assert_array_equal(xa, xb)


def _held(frames) -> int:
    """Bytes of the distinct arrays the frames hold (scan, perception, detections, P_D range image; an array
    shared by frames, as the road map, counted once)."""
    seen: dict[int, int] = {}

    def add(v) -> None:
        if isinstance(v, (np.ndarray, bytes)):
            seen[id(v)] = v.nbytes if isinstance(v, np.ndarray) else len(v)
        elif hasattr(v, "__dict__") or hasattr(v, "__slots__"):
            for name in getattr(v, "__slots__", ()) or vars(v):
                add(getattr(v, name))

    for sf in frames:
        for part in (sf.scan, sf.perception, sf.detections, sf.pd_scan, sf.pd):
            if part is not None and not callable(part) or isinstance(part, LightPD):
                add(part)
    return sum(seen.values())


def test_light_frames_track_as_full_ones_and_hold_a_fraction(scn, full):
    light = list(testbed.sense(scn, light=True))
    _same(_rows(testbed.track(light, "jpda-kf", scn)), _rows(testbed.track(full, "jpda-kf", scn)))
    for a, b in zip(full, light):
        assert b.perception is None and b.pd_scan is None and len(b.scan.points) == 0
        np.testing.assert_array_equal(a.detections.z, b.detections.z)
        np.testing.assert_array_equal(a.visibility[0], b.visibility[0])
        assert isinstance(b.pd, LightPD)
        np.testing.assert_array_equal(b.pd.scan().ranges, a.pd_scan.ranges)  # bit-identical range image
        xy = a.truth.xy[1:]
        np.testing.assert_array_equal(b.pd(xy, 0.9), a.pd(xy, 0.9))
        np.testing.assert_array_equal(b.pd(xy, 0.9, np.ones(len(xy), bool)), a.pd(xy, 0.9, np.ones(len(xy), bool)))
    ratio = _held(full) / _held(light)
    assert ratio > 100, ratio  # measured: 205 on 2 s of cut_in_out (4.0 MB against 20 kB a frame)


def test_packed_ranges_round_trip():
    r = np.full((4, 3), np.inf)
    r[1, 2], r[3, 0], r[0, 0] = 12.346, 0.002, 130.0
    r[np.isfinite(r)] = np.rint(r[np.isfinite(r)] / 0.002) * 0.002
    for dtype in (np.uint16, np.uint32):
        np.testing.assert_array_equal(PackedRanges(r, dtype).dense(), r)
    big = np.full((2250, 32), np.inf)
    assert PackedRanges(big, np.uint16).nbytes < 1000  # nothing but "no return" packs to almost nothing


def test_sense_with_a_cache_senses_once_into_runs_cache_and_streams_from_it(scn, full, tmp_path):
    cache = tmp_path / "cache"
    first = list(testbed.sense(scn, sensing_cache=cache))
    assert SensingCache(cache).has(scn) and len(first) == len(full) == scn.n_frames
    entries = sorted(p.name for p in cache.iterdir() if not p.name.startswith("."))
    again = list(testbed.sense(scn, sensing_cache=cache, light=True))
    res = testbed.run(scn, tracker="gnn-kf", sensing_cache=cache)  # run reads the entry sense wrote
    assert sorted(p.name for p in cache.iterdir() if not p.name.startswith(".")) == entries and len(entries) == 1
    live = _rows(testbed.track(full, "gnn-kf", scn))
    _same(_rows(testbed.track(first, "gnn-kf", scn)), live)
    _same(_rows(testbed.track(again, "gnn-kf", scn)), live)
    ev = testbed.score_frames(testbed.track(again, "gnn-kf", scn), scn)
    assert ev.scores.to_dict() == res.scores.to_dict() and ev.metrics == res.metrics


def _equal(a: dict, b: dict) -> None:
    assert a.keys() == b.keys()
    for k in a:
        x, y = a[k], b[k]
        assert (isinstance(x, float) and math.isnan(x) and math.isnan(y)) or x == y, (k, x, y)


def test_score_frames_equals_the_runs_scores(scn, full):
    for name in ("jpda-kf", "nn-kf"):
        res = testbed.run(scn, tracker=name)
        ev = testbed.score_frames(testbed.track(full, name, scn), scn)
        _equal(ev.scores.to_dict(), res.scores.to_dict())  # every thesis score and ours
        _equal(ev.metrics, res.metrics)  # every MOT metric, visible and *_all
        assert len(ev.metrics) >= 8 and res.scores.cars_seen == 3


def test_score_frames_of_a_scenario_name_and_of_user_pairs(scn, full):
    from roadtrack.testbed.tracking import TrackSet

    pairs = [(sf, TrackSet(ids=np.arange(1, len(sf.truth.ids)), xy=sf.truth.xy[1:])) for sf in full]
    ev = testbed.score_frames(pairs, scn)  # the truth itself as tracks: every seen car, no error
    assert ev.scores.pos_rmse_m == pytest.approx(0.0, abs=1e-12) and ev.scores.false_tracks == 0
    assert ev.metrics["hota"] == pytest.approx(1.0, abs=1e-9)


def _one_line(err: pytest.ExceptionInfo, *needles: str) -> None:
    text = str(err.value)
    assert "\n" not in text and all(n in text for n in needles), text


def test_bad_arguments_are_one_line_errors_at_the_call(scn, full, tmp_path):
    a_file = tmp_path / "a_file"
    a_file.write_text("x")
    with pytest.raises(ConfigError) as err:
        testbed.sense(scn, sensing_cache=a_file)
    _one_line(err, "sensing_cache", "is a file, not a folder")
    with pytest.raises(ConfigError) as err:
        testbed.sense(scn, sensing_cache=a_file / "sub")
    _one_line(err, "sensing_cache", "which is a file")
    with pytest.raises(ConfigError) as err:
        testbed.sense(scn, sensing_cache=3)
    _one_line(err, "sensing_cache", "expected a folder path, got int")
    with pytest.raises(ConfigError) as err:
        testbed.sense(scn, light="yes")
    _one_line(err, "light", "expected True or False")
    with pytest.raises(ConfigError) as err:
        testbed.sense(scn, policy=lambda obs, info: 1, sensing_cache=tmp_path / "c")
    _one_line(err, "sensing_cache", "policy")
    with pytest.raises(ConfigError) as err:
        testbed.run(scn, tracker="jpda-kf", sensing_cache=a_file)
    _one_line(err, "sensing_cache", "is a file")
    with pytest.raises(ValueError) as err:
        testbed.track(full, "jpda-nosuch", scn)  # at the call, before any frame is read
    _one_line(err, "unknown tracker name 'jpda-nosuch'")
    with pytest.raises(ConfigError) as err:
        testbed.track(5, "jpda-kf", scn)
    _one_line(err, "frames", "not iterable")
    with pytest.raises(ConfigError) as err:
        next(testbed.track([1, 2], "jpda-kf", scn))
    _one_line(err, "frames", "item 0 is a int")
    with pytest.raises(ConfigError) as err:
        testbed.score_frames([("a", "b")], scn)
    _one_line(err, "pairs", "item 0 is a tuple")
    pairs = list(testbed.track(full[:3], "jpda-kf", scn))
    with pytest.raises(ConfigError) as err:
        testbed.score_frames([pairs[1], pairs[0]], scn)
    _one_line(err, "pairs", "time order")
    with pytest.raises(ConfigError) as err:
        testbed.score_frames(None, scn)
    _one_line(err, "pairs", "not iterable")


def test_registering_a_plugin_checks_its_name_and_kind():
    from roadtrack.trackers.filters import FILTERS, FilterKind, ModelParams

    kf = FILTERS["kf"]
    with pytest.raises(ValueError, match="'kf' is a built-in filter"):
        trackers.register_filter("kf", kf)
    with pytest.raises(ValueError, match="'imm' is a built-in filter"):
        trackers.register_filter("imm", kf)
    with pytest.raises(ValueError, match="lower-case letters"):
        trackers.register_filter("My_Filter", kf)
    with pytest.raises(TypeError, match="expected a roadtrack.trackers.filters.params.FilterKind, got a dict"):
        trackers.register_filter("mine", {})
    with pytest.raises(TypeError, match="params must be a dataclass"):
        trackers.register_filter("mine", FilterKind(dict, kf.build, "x"))
    with pytest.raises(ValueError, match="'jpda' is a built-in associator"):
        trackers.register_associator("jpda", trackers.ASSOCIATORS["pda"])
    assert "mine" not in FILTERS and ModelParams is kf.params


def test_a_cache_entry_with_a_bad_range_image_is_sensed_again(scn, full, tmp_path):
    """The range images are read a batch at a time (testbed.sensing.cache.RangeBlobs), yet checked before the
    first frame: one of the wrong size makes the entry damaged (one warning line) and it is sensed again."""
    import warnings

    import pyarrow as pa
    import pyarrow.parquet as pq

    from roadtrack.testbed.sensing.cache import CacheWarning

    cache = tmp_path / "cache"
    sum(1 for _ in testbed.sense(scn, sensing_cache=cache))
    path = SensingCache(cache).entry(scn) / "ranges.parquet"
    table = pq.read_table(path)
    blobs = table.column("ranges").to_pylist()
    blobs[len(blobs) // 2] = blobs[len(blobs) // 2][:-2]
    pq.write_table(table.set_column(table.column_names.index("ranges"), "ranges", pa.array(blobs, pa.binary())),
                   path)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        again = list(testbed.sense(scn, sensing_cache=cache, light=True))
    mine = [str(w.message) for w in caught if issubclass(w.category, CacheWarning)]
    assert len(mine) == 1 and "a range image is not of" in mine[0] and "\n" not in mine[0]
    _same(_rows(testbed.track(again, "jpda-kf", scn)), _rows(testbed.track(full, "jpda-kf", scn)))
    assert SensingCache(cache).has(scn)
