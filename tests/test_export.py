"""`testbed export RUN --format html` (issue 34.3): a self-contained top-down replay, its data the run's own."""
from __future__ import annotations

import json
import re
from html.parser import HTMLParser

import numpy as np
import pandas as pd
import pytest

from roadtrack.testbed.config import ConfigError
from roadtrack.testbed.export import FORMATS, export_run
from roadtrack.testbed.export.html import thin_line
from roadtrack.testbed.recording.slots import track_colours

from conftest import cli


class _Page(HTMLParser):
    """The page's scripts (attributes, text) and whether any element loads something from elsewhere."""

    def __init__(self):
        super().__init__()
        self.scripts, self.external, self._in = [], [], None

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        if tag == "script":
            self._in = [a, ""]
        for key in ("src", "href"):
            if a.get(key):
                self.external.append((tag, a[key]))

    def handle_data(self, data):
        if self._in is not None:
            self._in[1] += data

    def handle_endtag(self, tag):
        if tag == "script" and self._in is not None:
            self.scripts.append(tuple(self._in))
            self._in = None


def test_html_export_is_one_parsable_self_contained_page_with_the_runs_data(short_run):
    out, _ = short_run
    proc = cli("export", str(out), "--format", "html", timeout=120)
    assert proc.returncode == 0, proc.stderr
    path = out / "replay.html"
    assert f"wrote {path}" in proc.stdout
    page = _Page()
    page.feed(path.read_text(encoding="utf-8"))
    assert page.external == []  # nothing fetched at view time
    (data_text,) = [text for attrs, text in page.scripts if attrs.get("type") == "application/json"]
    data = json.loads(data_text)
    truth, tracks = pd.read_parquet(out / "truth.parquet"), pd.read_parquet(out / "tracks.parquet")
    n = int(truth["frame"].max()) + 1
    assert data["meta"]["frames"] == n == len(data["time"]) and data["meta"]["tracker"] == "nn-kf"
    for key, table in (("truth", truth), ("tracks", tracks)):
        start = data[key]["start"]
        assert len(start) == n + 1 and start[-1] == len(table) == len(data[key]["x"])
    f = 40  # frame 40's tracks, in the page and in the table
    rows = tracks[tracks["frame"] == f].sort_values("track_id")
    a, b = data["tracks"]["start"][f], data["tracks"]["start"][f + 1]
    got = sorted(zip(data["tracks"]["id"][a:b], data["tracks"]["x"][a:b]))
    np.testing.assert_allclose([x for _, x in got], rows["x"], atol=0.006)
    want = {str(t): "#" + bytes(c.tolist()).hex() for t, c in track_colours(tracks).items()}
    assert data["colours"] == want  # the viewer's colours
    ev = pd.read_parquet(out / "events.parquet")
    assert [e["n"] for e in data["events"]] == ev["event"].tolist()
    assert data["events"][0]["text"] == "relabel of car 2: T2 -> T3 (merge)"
    assert len(data["lanes"]) >= 4 and all(len(ln) >= 4 and len(ln) % 2 == 0 for ln in data["lanes"])


def test_export_refuses_an_unknown_format_and_a_folder_that_is_not_a_run(tmp_path, short_run):
    with pytest.raises(ConfigError, match="allowed: " + ", ".join(sorted(FORMATS))):
        export_run(short_run[0], "nuscenes")
    with pytest.raises(ConfigError, match="not a run folder"):
        export_run(tmp_path, "html")
    proc = cli("export", str(tmp_path), "--format", "html", timeout=60)
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1 and proc.stderr.startswith("error: ")


def test_a_straight_lane_border_keeps_its_two_ends_and_a_curve_its_points():
    straight = np.column_stack([np.arange(0.0, 100.0, 5.0), np.full(20, 4.0)])
    np.testing.assert_array_equal(thin_line(straight), straight[[0, -1]])
    t = np.linspace(0.0, np.pi / 2, 30)
    arc = np.column_stack([20 * np.cos(t), 20 * np.sin(t)])
    assert len(thin_line(arc)) == 30
