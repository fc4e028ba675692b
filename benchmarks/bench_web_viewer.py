"""The web viewer on a run, in headless Chromium: how long until it shows the last frame, and screenshots.

    .venv/bin/python benchmarks/bench_web_viewer.py RUN [--at SECONDS] [--settle] [--shot out.png [--wait 3] [--views]]
                                                     [--port 19190] [--timeout 600]

Starts ``testbed view RUN --web`` (with ``--at``: opened at that time), opens the address it prints in a
headless Chromium (benchmarks/support/cdp.py; Debian's ``chromium``, software WebGL) and reads the viewer's state
from the page (``WebHandle.viewer_state()``, a protobuf ``GetStateResponse`` decoded here) every 0.1 s.
Prints the seconds from opening the page to: the viewer running, the recording's last frame received (the
``frame`` timeline's end reaching the run's last frame), and the cursor standing on it (or on ``--at``).
``--settle`` then takes a screenshot every 5 s until two in a row show the same views (the top bar and the time
panel left out): the time the scene was fully drawn (the frame timeline can reach the end before every
entity's data is in). ``--shot`` saves a screenshot ``--wait`` seconds later (default 3; ``--views``: also the columns of the layout,
cropped: FILE_chase.png, FILE_topdown.png (with the legend), FILE_plots.png).
"""
from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent / "support"))
from cdp import Browser  # noqa: E402

REPO = Path(__file__).resolve().parent.parent


def decode(buf: bytes) -> dict[int, list]:
    """A protobuf message as {field: [values]}: varints as int, length-delimited as bytes."""
    out: dict[int, list] = {}
    i = 0
    while i < len(buf):
        tag, i = _varint(buf, i)
        kind = tag & 7
        if kind == 0:
            value, i = _varint(buf, i)
        elif kind == 2:
            n, i = _varint(buf, i)
            value, i = buf[i:i + n], i + n
        elif kind in (1, 5):
            step = 8 if kind == 1 else 4
            value, i = buf[i:i + step], i + step
        else:
            raise ValueError(f"wire type {kind}")
        out.setdefault(tag >> 3, []).append(value)
    return out


def _varint(buf: bytes, i: int) -> tuple[int, int]:
    value = shift = 0
    while True:
        b = buf[i]
        i += 1
        value |= (b & 0x7F) << shift
        shift += 7
        if not b & 0x80:
            return value, i


def state(browser: Browser) -> dict | None:
    """The page's recording: {timeline: (start, end)}, the cursor's timeline and time; None before any."""
    raw = browser.evaluate("window._handle ? Array.from(window._handle.viewer_state()) : null")
    if not raw:
        return None
    recordings = decode(bytes(raw)).get(3, [])
    if not recordings:
        return None
    rec = decode(recordings[0])
    ranges = {}
    for tl in rec.get(2, []):
        t = decode(tl)
        name = decode(t[1][0])[1][0].decode()
        r = decode(t[3][0]) if 3 in t else {}
        ranges[name] = (r.get(1, [None])[0], r.get(2, [None])[0])
    cursor = decode(rec[3][0]) if 3 in rec else {}
    timeline = decode(cursor[1][0])[1][0].decode() if 1 in cursor else None
    now = decode(cursor[3][0]).get(1, [0])[0] if 3 in cursor else None
    return dict(ranges=ranges, timeline=timeline, time=now)


def serve(run: str, port: int, at: float | None) -> tuple[subprocess.Popen, str]:
    """``testbed view RUN --web`` started, and the page address it printed."""
    cmd = [sys.executable, "-m", "roadtrack.testbed.cli", "view", run, "--web", "--port", str(port),
           *(["--at", str(at)] if at is not None else [])]
    proc = subprocess.Popen(cmd, cwd=REPO, stdout=subprocess.PIPE, text=True)
    line = proc.stdout.readline()
    m = re.search(r"(http://\S+)", line)
    if not m:
        proc.terminate()
        raise RuntimeError(f"no address from testbed view: {line!r}")
    return proc, m.group(1)


def last_frame(run: str) -> int:
    doc = json.loads((Path(run) / "scores.json").read_text())
    return int(doc["frames"]) - 1


def measure(url: str, last: int, at: float | None, browser: Browser, timeout_s: float) -> dict[str, float]:
    """Seconds from opening ``url`` to: the viewer running, the last frame received, the cursor in place."""
    t0 = time.monotonic()
    browser.open(url)
    marks: dict[str, float] = {}
    want = None if at is None else round(at * 1e9)
    while time.monotonic() - t0 < timeout_s and "cursor" not in marks:
        try:
            s = state(browser)
        except TimeoutError:  # the page's thread is busy loading (a long recording): not an answer, ask again
            marks.setdefault("page unresponsive from", time.monotonic() - t0)
            continue
        if s is None:
            try:
                if browser.evaluate("window._handle !== undefined"):
                    marks.setdefault("viewer running", time.monotonic() - t0)
            except TimeoutError:
                marks.setdefault("page unresponsive from", time.monotonic() - t0)
            time.sleep(0.1)
            continue
        marks.setdefault("viewer running", time.monotonic() - t0)
        end = s["ranges"].get("frame", (None, None))[1]
        if end is not None and end >= last:
            marks.setdefault("last frame received", time.monotonic() - t0)
            if want is None and s["timeline"] == "frame" and s["time"] == last or \
                    want is None and s["timeline"] == "sim_time" and s["time"] >= s["ranges"]["sim_time"][1] or \
                    want is not None and s["timeline"] == "sim_time" and s["time"] == want:
                marks["cursor"] = time.monotonic() - t0
        time.sleep(0.1)
    return marks


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run")
    ap.add_argument("--at", type=float)
    ap.add_argument("--shot")
    ap.add_argument("--wait", type=float, default=3.0, help="seconds from the cursor in place to the screenshot")
    ap.add_argument("--views", action="store_true")
    ap.add_argument("--settle", action="store_true", help="also measure the time until the views stop changing")
    ap.add_argument("--port", type=int, default=19190)
    ap.add_argument("--timeout", type=float, default=600.0)
    a = ap.parse_args()
    rrd = Path(a.run) / "run.rrd"
    proc, url = serve(a.run, a.port, a.at)
    try:
        with Browser(size=(1600, 1000)) as b:
            t0 = time.monotonic()
            marks = measure(url, last_frame(a.run), a.at, b, a.timeout)
            if a.settle and "cursor" in marks:
                marks["views settled"] = settle(b, t0, a.timeout)
            print(f"{rrd}: {os.path.getsize(rrd) / 1e6:.1f} MB; " + ", ".join(f"{k} {v:.1f} s" for k, v in marks.items()))
            if a.shot:
                time.sleep(a.wait)
                b.screenshot(a.shot)
                if a.views:
                    crop(a.shot)
    finally:
        proc.terminate()
        proc.wait(timeout=20)


def settle(browser: Browser, t0: float, timeout_s: float, every_s: float = 5.0) -> float:
    """Seconds from ``t0`` to the first of two screenshots ``every_s`` apart whose views (between the top bar
    and the time panel) are identical; NaN if none within ``timeout_s``."""
    import base64
    import io

    from PIL import Image

    def views() -> bytes:
        png = base64.b64decode(browser.call("Page.captureScreenshot", format="png")["data"])
        img = Image.open(io.BytesIO(png)).convert("RGB")
        return img.crop((0, 40, img.width, img.height - 50)).tobytes()

    last, when = views(), time.monotonic() - t0
    while time.monotonic() - t0 < timeout_s:
        time.sleep(every_s)
        now = views()
        if now == last:
            return when
        last, when = now, time.monotonic() - t0
    return float("nan")


def crop(path: str) -> None:
    """FILE_chase.png, FILE_topdown.png and FILE_plots.png: the default layout's columns cut out of FILE."""
    from PIL import Image

    img = Image.open(path)
    w, h = img.size
    left = round(w * 3 / 5.6)  # the layout's column shares 3 : 1.4 : 1.2
    mid = round(w * 4.4 / 5.6)
    stem = path.removesuffix(".png")
    img.crop((0, 0, left, h)).save(f"{stem}_chase.png")
    img.crop((left, 0, mid, h)).save(f"{stem}_topdown.png")
    img.crop((mid, 0, w, h)).save(f"{stem}_plots.png")


if __name__ == "__main__":
    main()
