"""A finished run's figures, drawn from its folder: ``timeline.png`` (testbed/scoring/timeline.py: each car seen
as a bar coloured by the confirmed track covering it, in the track's colour in the viewer, relabels and false
tracks marked, and the per-car position error).

    write_run_plots(folder) -> list[Path]
"""
from __future__ import annotations

from pathlib import Path

from ..recording.slots import track_colours
from ..scoring.timeline import car_timeline, draw_timeline
from .runfolder import read_run

TIMELINE = "timeline.png"


def write_run_plots(folder: str | Path) -> list[Path]:
    """Draw the run in ``folder``'s figures into it (a planted symlink is refused, testbed.common.safe_io)."""
    run = read_run(folder)
    scn = run.scenario
    rate = scn.rate_hz if scn is not None else 10.0
    tl = car_timeline(run.truth, run.tracks, scn.scoring if scn is not None else None)
    title = f"{run.scores.get('scenario', Path(folder).name)}, {run.scores.get('tracker', '?')}"
    return [draw_timeline(tl, Path(folder) / TIMELINE, rate, title, colours=track_colours(run.tracks),
                          events=run.events)]
