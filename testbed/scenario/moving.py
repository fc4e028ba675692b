"""The ``[moving_test]`` table: the moving-object test's settings (the test itself: testbed/tracking/moving.py)."""
from __future__ import annotations

from dataclasses import dataclass

from ..config import field, positive


@dataclass(frozen=True)
class MovingTestSpec:
    """The moving-object test (testbed/tracking/moving.py)."""

    enabled: bool = field(True, doc="report a track only once its ground speed over window_s has reached "
                          "min_speed_mps (static roadside objects are then never reported)")
    min_speed_mps: float = field(4.0, doc="ground speed over the window a track must reach once [m/s]",
                                 **positive())
    window_s: float = field(0.8, doc="the window: the speed is the net displacement of the track's position "
                            "over this time divided by it [s]", **positive())
    parts: int = field(4, doc="the speed must also be reached over each of this many equal parts of the window, so a "
                       "track that jumps between static objects is not taken for a moving one (1: over the "
                       "whole window only)", check=(lambda v: 1 <= v <= 20, "in [1, 20]"))
