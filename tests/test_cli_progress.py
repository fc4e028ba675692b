"""`testbed --version`, and a progress bar whose first estimate leaves out the set-up (issue 34.4)."""
from __future__ import annotations

import io
import time

from tqdm import tqdm

from roadtrack.testbed.cli.main import frame_progress, main


def test_version_prints_the_installed_version(capsys):
    from importlib.metadata import version

    assert main(["--version"]) == 0
    assert capsys.readouterr().out.strip() == f"roadtrack {version('roadtrack')}"


def test_the_progress_rate_starts_after_the_first_frame():
    """3 s of set-up and first frame, then frames of 20 ms: the rate is that of the frames after the first (the
    bar's old clock, started before the set-up, gave a first rate about 1/150 of it: one frame per 3 s)."""
    bar = tqdm(total=100, file=io.StringIO(), mininterval=0, smoothing=0)
    bar.start_t -= 3.0  # the set-up and the first frame
    on_frame = frame_progress(bar)
    on_frame(1, 100)
    for i in range(2, 7):
        time.sleep(0.02)
        on_frame(i, 100)
    rate = bar.format_dict["rate"] or (bar.n - bar.initial) / (time.time() - bar.start_t)
    assert bar.n == 6 and 20 < rate < 60  # frames per second of the 20 ms frames (sleep overshoots a little)
    bar.close()
