"""Sense once, track many (issue 18): a tracker run from the sensing cache is identical to a run from scratch; the
key changes with what changes sensing and only with that; a damaged entry is re-sensed with one warning line."""
from __future__ import annotations

import warnings

import numpy as np
import pandas as pd
import pytest

from roadtrack.testbed.pipeline.run import run_scenario
from roadtrack.testbed.scenario.spec import load_scenario
from roadtrack.testbed.sensing.cache import CacheWarning, SensingCache, sensing_key

SHORT = {"duration_s": 3.0}


def _tables(res) -> dict[str, pd.DataFrame]:
    return {name: log.table().to_pandas() for name, log in res.tables.items()}


def _same(a, b) -> None:
    ta, tb = _tables(a), _tables(b)
    for name in ta:
        pd.testing.assert_frame_equal(ta[name], tb[name], check_exact=True, obj=name)
    assert a.scores.to_dict() == pytest.approx(b.scores.to_dict(), nan_ok=True, rel=0, abs=0)
    assert a.metrics == pytest.approx(b.metrics, nan_ok=True, rel=0, abs=0)


@pytest.fixture(scope="module")
def scn():
    return load_scenario("cut_in_out", SHORT)


def test_a_run_from_the_cache_is_identical_to_one_from_scratch(scn, tmp_path):
    cache = tmp_path / "cache"
    scratch = run_scenario(scn, record=False, tracker="jpda-kf")
    storing = run_scenario(scn, record=False, tracker="jpda-kf", sensing_cache=cache)  # senses, stores
    assert SensingCache(cache).has(scn)
    reading = run_scenario(scn, record=False, tracker="jpda-kf", sensing_cache=cache)  # reads
    _same(scratch, storing)
    _same(scratch, reading)
    other = run_scenario(scn, record=False, tracker="imm-pda-kf", sensing_cache=cache)  # another tracker, same frames
    _same(run_scenario(scn, record=False, tracker="imm-pda-kf"), other)
    assert reading.timings_ms["raycast"] == 0.0 and reading.timings_ms["perception"] == 0.0


def test_the_key_follows_what_changes_sensing(scn):
    same = [load_scenario("cut_in_out", {**SHORT, k: v}) for k, v in
            (("tracker.name", "gnn-kf"), ("tracker.filter.sigma_w", 0.7), ("scoring.match_distance_m", 2.0),
             ("moving_test.enabled", False), ("record.lidar_every", 0))]
    assert {sensing_key(s) for s in same} == {sensing_key(scn)}
    other = [load_scenario("cut_in_out", {**SHORT, k: v}) for k, v in
             (("seed", 8), ("duration_s", 2.0), ("sensor.clutter.density_per_m2", 0.001),
              ("sensor.perception.cluster.scan_line_links", False), ("sensor.lidar.dropout", 0.05))]
    keys = {sensing_key(s) for s in other}
    assert len(keys) == len(other) and sensing_key(scn) not in keys


def test_a_damaged_entry_is_sensed_again_with_one_warning(scn, tmp_path):
    cache = tmp_path / "cache"
    first = run_scenario(scn, record=False, sensing_cache=cache)
    entry = SensingCache(cache).entry(scn)
    (entry / "detections.parquet").write_bytes(b"not parquet")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        again = run_scenario(scn, record=False, sensing_cache=cache)
    mine = [w for w in caught if issubclass(w.category, CacheWarning)]
    assert len(mine) == 1 and "damaged" in str(mine[0].message) and "\n" not in str(mine[0].message)
    _same(first, again)
    assert SensingCache(cache).has(scn)  # stored afresh


def test_an_interrupted_sensing_stores_nothing(scn, tmp_path):
    cache = tmp_path / "cache"

    def stop(i, n):
        if i == 5:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_scenario(scn, record=False, sensing_cache=cache, on_frame=stop)
    assert not SensingCache(cache).has(scn)
    assert not [p for p in cache.iterdir() if p.name.startswith(".") and "partial" in p.name]


def test_cached_frames_give_the_recording_without_points(scn, tmp_path):
    from rerun.chunk import RrdReader  # noqa: F401

    cache = tmp_path / "cache"
    run_scenario(scn, record=False, sensing_cache=cache)
    res = run_scenario(scn, out_dir=tmp_path / "r", record=True, sensing_cache=cache)
    assert (tmp_path / "r" / "run.rrd").stat().st_size > 50_000
    assert res.n_frames == scn.n_frames and np.isfinite(res.scores.tp_pct)
