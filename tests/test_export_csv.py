"""`testbed export RUN --format csv` (issue 31.4): the run's tables as CSV, equal to the parquet tables to the bit."""
from __future__ import annotations

import json
import os

import numpy as np
import pandas as pd
import pytest

from roadtrack.testbed.config import ConfigError
from roadtrack.testbed.export import export_run
from roadtrack.testbed.export.csv_tables import COV_COLUMNS

from conftest import cli


def test_csv_export_holds_every_table_bit_for_bit_with_r_and_the_flattened_covariance(short_run, short_run_csv):
    out, _ = short_run
    csv, proc = short_run_csv  # `testbed export RUN --format csv --out CSV`, run once for the session (conftest)
    assert proc.returncode == 0, proc.stderr
    assert f"wrote {csv}" in proc.stdout
    assert sorted(p.name for p in csv.iterdir()) == ["detections.csv", "events.csv", "tracks.csv", "truth.csv"]
    for name in ("truth", "detections", "events"):
        want = pd.read_parquet(out / f"{name}.parquet")
        got = pd.read_csv(csv / f"{name}.csv", float_precision="round_trip")
        assert list(got.columns) == list(want.columns)
        for col in want.columns:
            w = want[col].to_numpy()
            g = got[col].to_numpy()
            if w.dtype == bool:
                assert set(np.unique(g)) <= {0, 1}
                g = g.astype(bool)
            if w.dtype.kind == "f":
                np.testing.assert_array_equal(g, w)  # shortest round-trip form: the same float64, not close
            else:
                assert (g == w).all(), (name, col)
    det = pd.read_csv(csv / "detections.csv")
    assert {"r_xx", "r_xy", "r_yy"} <= set(det.columns) and (det.r_xx > 0).all() and (det.r_yy > 0).all()
    tracks = pd.read_parquet(out / "tracks.parquet")
    got = pd.read_csv(csv / "tracks.csv", float_precision="round_trip")
    assert list(got.columns) == [c for c in tracks.columns if c != "cov"] + list(COV_COLUMNS)
    np.testing.assert_array_equal(got[list(COV_COLUMNS)].to_numpy(), np.stack(tracks["cov"].to_numpy()))
    assert COV_COLUMNS[1] == "cov_x_y" and COV_COLUMNS[4] == "cov_y_x" and COV_COLUMNS[15] == "cov_vy_vy"
    np.testing.assert_array_equal(got[["x", "y", "vx", "vy", "score"]].to_numpy(),
                                  tracks[["x", "y", "vx", "vy", "score"]].to_numpy())
    assert (got["status"] == tracks["status"]).all() and (got["track_id"] == tracks["track_id"]).all()


def test_the_exported_tracks_csv_scores_as_the_runs_own_tracks(short_run, short_run_csv):
    out, _ = short_run
    csv, _ = short_run_csv
    own = cli("score", str(out), "--json", timeout=120)
    other = cli("score", str(out), "--tracks", str(csv / "tracks.csv"), "--json", timeout=120)
    assert own.returncode == 0 and other.returncode == 0, own.stderr + other.stderr
    a, b = json.loads(own.stdout), json.loads(other.stdout)
    assert a["scores"] == b["scores"] and a["mot_metrics"] == b["mot_metrics"]
    assert a["scores"]["cars_tracked"] == 3 and a["scores"]["relabel_events"] == 2  # the fixture's run (conftest)


def test_csv_export_refuses_a_file_a_link_and_a_planted_link_inside(short_run, tmp_path):
    out, _ = short_run
    (tmp_path / "afile").write_text("x")
    with pytest.raises(ConfigError, match="is a file; the csv format writes a folder"):
        export_run(out, "csv", tmp_path / "afile")
    (tmp_path / "elsewhere").mkdir()
    os.symlink(tmp_path / "elsewhere", tmp_path / "link")
    with pytest.raises(ConfigError, match="symbolic link"):
        export_run(out, "csv", tmp_path / "link")
    (tmp_path / "csv").mkdir()
    victim = tmp_path / "victim.txt"
    victim.write_text("keep me")
    os.symlink(victim, tmp_path / "csv" / "tracks.csv")
    proc = cli("export", str(out), "--format", "csv", "--out", str(tmp_path / "csv"), timeout=120)
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1 and "symbolic link" in proc.stderr
    assert victim.read_text() == "keep me" and os.path.islink(tmp_path / "csv" / "tracks.csv")
    assert os.listdir(tmp_path / "elsewhere") == []
