"""The viewer (issue 20): the recording's blueprint puts both 3-D views in the sensor car's frame (read back
from the file), ``testbed view --at`` moves the time cursor with the request rerun 0.41's viewer-control API
takes, and ``testbed view`` prints its address and none of rerun's INFO lines."""
from __future__ import annotations

import os
import re
import signal
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import pytest
from rerun.chunk import RrdReader

from roadtrack.testbed.pipeline.run import run_scenario
from roadtrack.testbed.recording.layout import CHASE_EYE, TOP_DOWN_EYE, TRAIL_S
from roadtrack.testbed.recording.recorder import Recorder
from roadtrack.testbed.recording.timecursor import set_time_request
from roadtrack.testbed.scenario.spec import load_scenario

REPO = Path(__file__).resolve().parent.parent


def _blueprint(rrd: Path) -> dict[str, dict]:
    """The blueprint store of ``rrd``: entity path -> {component: value} (last row)."""
    reader = RrdReader(str(rrd))
    (store,) = reader.blueprints()
    out: dict[str, dict] = {}
    for chunk in reader.stream(store=store):
        rb = chunk.to_record_batch()
        row = out.setdefault(chunk.entity_path, {})
        row.update({n: rb.column(n).to_pylist()[-1] for n in rb.schema.names if ":" in n})
    return out


def test_both_3d_views_are_in_the_sensor_cars_frame_with_their_eyes(tmp_path):
    rec = Recorder(tmp_path / "run.rrd", "blueprint", rate_hz=10.0)
    rec.close()
    bp = _blueprint(tmp_path / "run.rrd")
    views = {row["ViewBlueprint:display_name"][0]: path for path, row in bp.items()
             if row.get("ViewBlueprint:class_identifier") == ["3D"]}
    assert sorted(views) == ["chase (sensor car's frame)", "top-down (sensor car's frame)"]
    for name, eye in (("chase (sensor car's frame)", CHASE_EYE), ("top-down (sensor car's frame)", TOP_DOWN_EYE)):
        view = views[name]
        assert bp[view]["ViewBlueprint:space_origin"] == ["/world/ego"]
        assert bp[f"{view}/ViewContents"]["ViewContents:query"] == ["/world/**"]
        controls = bp[f"{view}/EyeControls3D"]
        for key in ("position", "look_target", "eye_up"):
            assert controls[f"EyeControls3D:{key}"] == [pytest.approx(eye[key], abs=1e-9)], (name, key)
        assert controls["EyeControls3D:kind"] == [2]  # orbital
        # no tracking entity: rerun re-frames a tracked entity's eye at 1.5x its size (layout.py says why)
        assert "EyeControls3D:tracking_entity" not in controls
        trail = bp[f"{view}/ViewContents/overrides/world/tracks/trajectories/visualizers"]["VisibleTimeRanges:ranges"]
        assert {"timeline": "sim_time", "range": {"start": -round(TRAIL_S * 1e9), "end": 0}} in trail
    top = bp[f"{views['top-down (sensor car' + chr(39) + 's frame)']}/EyeControls3D"]
    assert top["EyeControls3D:position"][0][2] >= 100.0  # highway scale: >= 100 m above the car


def _fields(buf: bytes) -> dict[int, object]:
    """A protobuf message's fields (last value each): varints as int, length-delimited as bytes."""
    out, i = {}, 0
    while i < len(buf):
        tag, i = _varint(buf, i)
        if tag & 7 == 0:
            out[tag >> 3], i = _varint(buf, i)
        else:
            n, i = _varint(buf, i)
            out[tag >> 3], i = buf[i:i + n], i + n
    return out


def _varint(buf: bytes, i: int) -> tuple[int, int]:
    value = shift = 0
    while True:
        value |= (buf[i] & 0x7F) << shift
        shift += 7
        i += 1
        if not buf[i - 1] & 0x80:
            return value, i


def test_the_time_request_is_set_time_cursor_on_sim_time_paused():
    req = _fields(set_time_request(8.25))
    assert list(req) == [6]  # ViewerControlRequest.set_time_cursor
    cursor = _fields(req[6])
    assert _fields(cursor[2]) == {1: b"sim_time"}  # Timeline.name
    assert _fields(cursor[3]) == {1: 8_250_000_000}  # TimelineTime.time [ns]
    assert cursor[5] == 1  # PLAY_STATE_PAUSED


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("run")
    run_scenario(load_scenario("cut_in_out", {"duration_s": 2.0, "record.level": "tracks"}), out_dir=out)
    return out


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.parametrize("at, message", [("-5", "argument --at: expected seconds >= 0, got -5"),
                                         ("soon", "argument --at: expected seconds >= 0, got 'soon'"),
                                         ("2.5", "error: --at: 2.5 s is past the end of the recording")])
def test_a_bad_start_time_is_one_line(run_dir, at, message):
    proc = subprocess.run([sys.executable, "-m", "roadtrack.testbed.cli", "view", str(run_dir), "--web", "--at", at],
                          cwd=REPO, capture_output=True, text=True, timeout=60)
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and len(lines) == 1 and message in lines[0], proc.stderr
    if at == "2.5":
        assert lines[0].endswith("run.rrd ends at 2 s); allowed: 0..2")


def test_view_prints_its_address_and_serves_the_page_with_the_start_time(run_dir):
    port = _free_port()
    env = dict(os.environ)
    env.pop("RUST_LOG", None)
    proc = subprocess.Popen([sys.executable, "-m", "roadtrack.testbed.cli", "view", str(run_dir), "--web", "--port", str(port),
                             "--at", "1.5"], cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    try:
        line = proc.stdout.readline()
        m = re.fullmatch(r"web viewer \(opening at 1\.5 s, paused\), Ctrl-C to stop: (http://127\.0\.0\.1:(\d+)/"
                         r"\?url=rerun%2Bhttp%3A%2F%2F127\.0\.0\.1%3A\d+%2Fproxy)\n", line)
        assert m and int(m.group(2)) == port, line
        page = _get(m.group(1), timeout_s=30)
        request = ",".join(str(b) for b in set_time_request(1.5))
        assert b"window._handle" in page and f"new Uint8Array([{request}])".encode() in page
        assert b"re_viewer.js" in page  # rerun's own page underneath
    finally:
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=30)
    assert " INFO " not in err and "\x1b[32m INFO" not in err, err  # rerun's INFO lines are off


def _get(url: str, timeout_s: float) -> bytes:
    end = time.monotonic() + timeout_s
    while True:
        try:
            with urllib.request.urlopen(url, timeout=5) as r:
                return r.read()
        except OSError:
            if time.monotonic() > end:
                raise
            time.sleep(0.2)
