"""Compacting a finished recording (testbed/recording/rrd.py): the chunks are merged and every row is kept,
read back with rerun's own reader; a file rerun cannot compact is kept byte for byte with the reason; a run
whose compaction fails still ends with its recording and one warning."""
from __future__ import annotations

import collections
import warnings
from pathlib import Path

import numpy as np
import pytest
import rerun as rr
from rerun.chunk import RrdReader

from roadtrack.testbed.pipeline.run import run_scenario
from roadtrack.testbed.recording.rrd import Compaction, compact
from roadtrack.testbed.scenario.spec import load_scenario

N_SERIES, N_SENDS, ROWS = 40, 30, 5  # 1,200 chunks: rerun writes the count as "1 200"


def _chunks(rrd: Path) -> tuple[int, dict[str, list[float]]]:
    """Number of data chunks, and each series' values in frame order."""
    n, rows = 0, collections.defaultdict(list)
    for chunk in RrdReader(str(rrd)).stream():
        if not chunk.entity_path.startswith("/s/"):
            continue
        n += 1
        rb = chunk.to_record_batch()
        frames = rb.column("frame").to_pylist()
        values = [v[0] for v in rb.column("Scalars:scalars").to_pylist()]
        rows[chunk.entity_path] += list(zip(frames, values))
    return n, {k: [v for _, v in sorted(r)] for k, r in rows.items()}


def _many_small_chunks(path: Path) -> None:
    """N_SERIES series, each sent in N_SENDS columns of ROWS rows: one chunk per send, as a run's series are."""
    rec = rr.RecordingStream("compact-test", recording_id="compact-test")
    rec.save(str(path), write_footer=False)
    for s in range(N_SENDS):
        frames = np.arange(s * ROWS, (s + 1) * ROWS)
        for k in range(N_SERIES):
            rec.send_columns(f"s/{k}", indexes=[rr.TimeColumn("frame", sequence=frames)],
                             columns=rr.Scalars.columns(scalars=np.sin(frames * 0.1 + k)))
    rec.flush()
    rec.disconnect()


def test_compaction_merges_the_chunks_and_keeps_every_row(tmp_path):
    path = tmp_path / "many.rrd"
    _many_small_chunks(path)
    before, rows = _chunks(path)
    assert before == N_SERIES * N_SENDS
    assert compact(path) is None
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # rerun's reader warns about a file without footer: compaction adds it
        after, rows_after = _chunks(path)
    assert after <= N_SERIES  # one chunk per series at most
    assert rows_after.keys() == rows.keys()
    for k, values in rows.items():
        assert len(values) == N_SENDS * ROWS
        np.testing.assert_array_equal(rows_after[k], values)
    assert not list(tmp_path.glob(".*tmp*"))  # no temporary left


def test_a_file_rerun_cannot_read_is_kept_as_it_was(tmp_path):
    path = tmp_path / "broken.rrd"
    data = b"not a recording " * 4096
    path.write_bytes(data)
    why = compact(path)
    assert why and "rerun rrd optimize" in why
    assert path.read_bytes() == data
    assert not list(tmp_path.glob(".*tmp*"))


def test_a_run_whose_compaction_fails_keeps_its_recording_and_warns(tmp_path, monkeypatch):
    monkeypatch.setenv("RERUN_CLI_PATH", "/bin/false")  # "rerun" that fails at once
    scn = load_scenario("cut_in_out", {"duration_s": 1.0})
    with pytest.warns(RuntimeWarning, match="not compacted .*exited with 1"):
        res = run_scenario(scn, out_dir=tmp_path / "run", record=True)
    rows = collections.Counter()
    for chunk in RrdReader(str(tmp_path / "run" / "run.rrd")).stream():
        rows[chunk.entity_path] += chunk.num_rows
    assert rows["/world/truth/vehicles"] == res.n_frames


def test_a_cancelled_compaction_leaves_the_original_and_no_temporary(tmp_path):
    path = tmp_path / "many.rrd"
    _many_small_chunks(path)
    data = path.read_bytes()
    job = Compaction(path)
    job.cancel()
    assert path.read_bytes() == data
    assert not list(tmp_path.glob(".*tmp*"))
    assert job.wait() == "cancelled"
