"""The recording's default blueprint: a chase view and a top-down view in the sensor car's frame, the legend,
the counts and the per-track diagnostics (one tab per quantity, testbed/recording/diagnostics.py).

Why the views' origin is the sensor car (``world/ego``, its pose logged there as a Transform3D each frame) and
not ``EyeControls3D(tracking_entity=...)``: rerun 0.41 follows a tracked entity through the bounding box of
what is drawn *at that path*; ``world/ego`` holds only a transform, so it has no box and the eye stayed where
the blueprint put it (at the road start). Tracking a drawn entity (the ego's box) does follow it, but rerun
then re-frames the eye at 1.5x the entity's bounding-sphere radius (about 4 m from a car), throwing away the
blueprint's distance. A view whose origin is the car's frame draws every entity relative to that frame, so
the blueprint's eye (position and look target in metres in the car's frame: x forward, y left, z up) moves
with the car, in the native and the web viewer alike.
"""
from __future__ import annotations

import rerun.blueprint as rrb

from .diagnostics import titles

EGO = "/world/ego"
CHASE_EYE = dict(position=[-45.0, -30.0, 35.0], look_target=[15.0, 0.0, 0.0], eye_up=[0.0, 0.0, 1.0])
"""Behind, left of and above the car, looking 15 m ahead of it."""
TOP_DOWN_EYE = dict(position=[15.0, 0.0, 160.0], look_target=[15.0, 0.0, 0.0], eye_up=[1.0, 0.0, 0.0])
"""160 m straight above a point 15 m ahead of the car, its heading up: about +-80 m along the road in view
(the LiDAR reaches 70 m)."""
TRAIL_S = 5.0  # the track trails (a dot every 0.5 s, testbed/recording/scene.py) show the last 5 s


def blueprint(rate_hz: float = 10.0) -> rrb.Blueprint:
    """The chase view, the top-down view, the legend, the count plots and the diagnostics tabs; panels
    collapsed."""
    hidden = {"/world/lidar/truth": rrb.EntityBehavior(visible=False)}
    trails = {"/world/tracks/trajectories": trail_ranges(rate_hz)}
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(name="chase (sensor car's frame)", origin=EGO, contents="/world/**",
                              eye_controls=rrb.EyeControls3D(kind=rrb.Eye3DKind.Orbital, **CHASE_EYE),
                              overrides={**hidden, **trails}),
            rrb.Vertical(
                rrb.Spatial3DView(name="top-down (sensor car's frame)", origin=EGO, contents="/world/**",
                                  eye_controls=rrb.EyeControls3D(kind=rrb.Eye3DKind.Orbital, **TOP_DOWN_EYE),
                                  line_grid=rrb.LineGrid3D(visible=False), overrides={**hidden, **trails}),
                rrb.Spatial2DView(name="legend", origin="/legend"),
                rrb.TextLogView(name="events (relabels, false tracks, missed cars)", origin="/events"),
                row_shares=[1.4, 1, 0.45]),
            _plots(),
            column_shares=[3, 1.4, 1.2],
        ),
        rrb.BlueprintPanel(state="collapsed"),
        rrb.SelectionPanel(state="collapsed"),
        rrb.TimePanel(state="collapsed"),
    )


def trail_ranges(rate_hz: float) -> rrb.VisibleTimeRanges:
    """The last :data:`TRAIL_S` seconds on both timelines (each frame logs one segment per confirmed track)."""
    return rrb.VisibleTimeRanges([
        rrb.VisibleTimeRange("sim_time", start=rrb.TimeRangeBoundary.cursor_relative(seconds=-TRAIL_S),
                             end=rrb.TimeRangeBoundary.cursor_relative()),
        rrb.VisibleTimeRange("frame", start=rrb.TimeRangeBoundary.cursor_relative(seq=-round(TRAIL_S * rate_hz)),
                             end=rrb.TimeRangeBoundary.cursor_relative()),
    ])


def _plots() -> rrb.Vertical:
    return rrb.Vertical(
        rrb.TimeSeriesView(name="tracks", origin="/metrics",
                           contents=["/metrics/tracks_confirmed", "/metrics/tracks_tentative"]),
        rrb.TimeSeriesView(name="detections", origin="/metrics",
                           contents=["/metrics/detections", "/metrics/clutter_detections"]),
        rrb.TimeSeriesView(name="perception (measured against truth)", origin="/metrics",
                           contents=["/metrics/ground_precision", "/metrics/ground_recall", "/metrics/pd_in_range"]),
        rrb.TimeSeriesView(name="merged / split / rejected", origin="/metrics",
                           contents=["/metrics/merged_detections", "/metrics/split_detections",
                                     "/metrics/rejected_objects"]),
        rrb.Tabs(*(rrb.TimeSeriesView(name=title, origin=f"/diagnostics/{key}", plot_legend=rrb.PlotLegend(
            visible=False)) for key, title in titles()),
                 name="track diagnostics, one tab per quantity (a line per track, in its colour in the scene)"),
        row_shares=[1, 1, 1, 1, 2.4],
    )
