"""Scores of what ``track`` yields: the (SensedFrame, TrackSet) pairs of a scenario scored as ``run`` scores its
tables, without building the truth table by hand (``testbed.score_frames``)."""
from __future__ import annotations

from typing import Iterable

from ..config import ConfigError
from ..scenario.spec import Scenario
from ..scoring.evaluate import Evaluation
from ..sensing import SensedFrame
from ..tracking import TrackSet
from .run import log_tables, score_tables
from .tables import detections_log, tracks_log, truth_log


def score_frames(pairs: Iterable[tuple[SensedFrame, TrackSet]], scn: Scenario) -> Evaluation:
    """The thesis scores and MOT metrics (testbed.scoring.evaluate.Evaluation) of ``pairs``, the (SensedFrame,
    TrackSet) of each frame as testbed.track yields them (the TrackSet's ``status``: only "confirmed" tracks are
    scored), with ``scn``'s scoring settings: the same as ``run(scn, tracker).scores`` and ``.metrics`` for the
    same frames. The pairs are read once, one at a time (only the truth and track rows are kept). ConfigError
    (one line) when an item is not such a pair or the frames are not in time order."""
    try:
        items = iter(pairs)
    except TypeError:
        raise ConfigError("pairs", f"expected the (SensedFrame, TrackSet) pairs testbed.track yields, got a "
                          f"{type(pairs).__name__}, which is not iterable") from None
    truth_t, det_t, trk_t = truth_log(), detections_log(), tracks_log()
    last = -1
    for k, item in enumerate(items):
        if not (isinstance(item, tuple) and len(item) == 2 and isinstance(item[0], SensedFrame)
                and isinstance(item[1], TrackSet)):
            raise ConfigError("pairs", f"item {k} is a {type(item).__name__}, not a (SensedFrame, TrackSet) pair "
                              f"as testbed.track yields")
        sensed, ts = item
        if sensed.index <= last:
            raise ConfigError("pairs", f"item {k} is frame {sensed.index}, after frame {last}: the frames must "
                              f"come in time order, each once")
        last = sensed.index
        log_tables(sensed.truth, sensed.visibility, sensed.detections, ts, truth_t, det_t, trk_t)
    scores, metrics = score_tables(scn, truth_t, trk_t, last + 1)
    return Evaluation(scores, metrics)
