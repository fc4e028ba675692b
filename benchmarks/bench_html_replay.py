"""The HTML replay (`testbed export RUN --format html`) in headless Chromium: how long until it is drawn.

    .venv/bin/python benchmarks/bench_html_replay.py RUN [--repeat 3] [--shot out.png] [--at SECONDS | --event N]

Exports RUN's replay.html (if missing), then, --repeat times, starts a fresh headless Chromium (software
rendering, benchmarks/support/cdp.py), opens the file and waits for the page's ``data-ready-ms`` (set once its
first frame is drawn). Prints per try: the seconds from opening the page to drawn (wall clock, browser start
excluded) and the page's own ready time, then the size of the file. ``--shot`` saves a screenshot of the last try.
Measured 2026-12-06: 60 s of highway_benchmark (0.9 MB) drawn in 0.23-0.32 s (with the browser's start, 1.5-2 s);
the whole 427 s benchmark (8.2 MB) in 0.29-0.31 s.
"""
from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent / "support"))
from cdp import Browser  # noqa: E402

REPO = Path(__file__).resolve().parent.parent


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("run")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--shot")
    ap.add_argument("--at", type=float)
    ap.add_argument("--event", type=int)
    args = ap.parse_args()
    page = Path(args.run) / "replay.html"
    if not page.is_file():
        subprocess.run([sys.executable, "-m", "roadtrack.testbed.cli", "export", args.run, "--format", "html"], cwd=REPO,
                       check=True)
    frag = f"#event={args.event}" if args.event else f"#t={args.at}" if args.at is not None else ""
    url = page.resolve().as_uri() + frag
    for k in range(args.repeat):
        with Browser(size=(1500, 850)) as b:
            t0 = time.perf_counter()
            b.open(url)
            ready = b.wait_for("document.body && document.body.dataset.readyMs", timeout_s=60)
            wall = time.perf_counter() - t0
            print(f"try {k + 1}: drawn {wall:.2f} s after opening (page's own ready time {float(ready) / 1000:.2f} s)")
            if args.shot and k == args.repeat - 1:
                b.screenshot(args.shot)
    print(f"{page}: {page.stat().st_size / 1e6:.2f} MB")
    return 0


if __name__ == "__main__":
    sys.exit(main())
