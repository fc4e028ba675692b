"""roadtrack's testbed: highway-env traffic -> synthetic LiDAR -> perception -> any tracker -> scores and a rerun
recording. The public API (docs/api.md), small enough to remember:

    load_scenario(name_or_path, overrides=None) -> Scenario
    sense(scenario, sensing_cache=None, light=False) -> iterator of SensedFrame (truth, detections, visibility, pd)
    track(frames, tracker, scenario)      -> iterator of (SensedFrame, TrackSet)
    score_frames(pairs, scenario)         -> Evaluation of what track yields (the same as run's scores)
    run(scenario, tracker=None, out=None, sensing_cache=None) -> RunResult (tables, scores, MOT metrics)
    read_run(folder)                      -> RunData (the tables as DataFrames, scores.json, the scenario)
    score(truth, tracks, scoring=None)    -> Evaluation (thesis scores and MOT metrics of plain tables)

A tracker is anything with ``step(frame: Frame) -> TrackSet`` (testbed.tracking); everything else may change.
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Any

__all__ = ["Frame", "TrackSet", "load_scenario", "read_run", "run", "score", "score_frames", "sense", "track"]

if TYPE_CHECKING:
    from .scoring.evaluate import score
    from .pipeline.runfolder import read_run
    from .world import load_scenario
    from .tracking import Frame, TrackSet


def sense(scenario, policy=None, *, sensing_cache=None, light: bool = False):
    """The frames of ``scenario`` (a Scenario, a shipped scenario's name or a file) sensed one by one
    (testbed.sensing.SensedFrame); ``policy``: the ego's policy for a scenario with ``[env]``. ``sensing_cache``
    (a folder, the one ``run`` takes): each traffic is sensed once into it, then streamed from it.
    ``light``: frames without the point cloud (tens of kB each instead of megabytes; testbed.sensing.light)."""
    from .sensing.stream import sensed_frames

    return sensed_frames(_scenario(scenario), policy, sensing_cache, light)


def track(frames, tracker, scenario):
    """Feed sensed ``frames`` to ``tracker`` (a built-in name, ``module:Name``, a factory or a tracker object):
    an iterator of (SensedFrame, TrackSet) with the moving-object test's status (testbed.pipeline.run.track)."""
    from .pipeline.run import track as _track

    return _track(frames, tracker, _scenario(scenario))


def score_frames(pairs, scenario):
    """The thesis scores and MOT metrics (an Evaluation, as ``score`` gives) of the (SensedFrame, TrackSet) pairs
    ``track`` yields for ``scenario``: the same as ``run(scenario, tracker).scores`` and ``.metrics`` on the same
    frames, with no table built by hand (testbed.pipeline.frames_score)."""
    from .pipeline.frames_score import score_frames as _score_frames

    return _score_frames(pairs, _scenario(scenario))


def run(scenario, tracker=None, out=None, record: bool = True, policy=None, on_frame=None, sensing_cache=None):
    """Run ``scenario`` end to end with ``tracker`` (default: the scenario's; a built-in or named tracker such as
    ``stonesoup-jpda-kf``, ``module:Name``, a factory or an object); with ``out`` write the run folder (tables,
    scores.json and, with ``record``, run.rrd); with ``sensing_cache`` (a folder) sense each traffic once and
    track from it after (bit-identical). Returns the RunResult (testbed.pipeline.run.run_scenario)."""
    from .pipeline.run import run_scenario

    return run_scenario(_scenario(scenario), out_dir=out, record=record and out is not None, tracker=tracker,
                        on_frame=on_frame, policy=policy, sensing_cache=sensing_cache)


def _scenario(scenario):
    from .scenario.spec import Scenario
    from .world import load_scenario

    return scenario if isinstance(scenario, Scenario) else load_scenario(scenario)


def __getattr__(name: str) -> Any:  # the rest of the API, imported on first use (the CLI starts fast)
    if name == "load_scenario":
        from .world import load_scenario

        return load_scenario
    if name == "read_run":
        from .pipeline.runfolder import read_run

        return read_run
    if name == "score":
        from .scoring.evaluate import score

        return score
    if name in ("Frame", "TrackSet"):
        from . import tracking

        return getattr(tracking, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
