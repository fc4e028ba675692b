"""The scene's colours and styles, in one place: the 3-D scene (scene.py, recorder.py) draws with them and the
legend (legend.py) is drawn from them, so the two cannot disagree. RGB or RGBA, uint8.

Styles: only the sensor car is a solid opaque box; only the SVSF boundary layers are translucent filled
boxes; truth and fitted boxes are wireframes; the occlusion shadows are faint thin outlines.
"""
from __future__ import annotations

import numpy as np

EGO = (255, 70, 0)  # the sensor car: solid vermilion box (visible on the viewer's light and dark themes)
ROAD = (200, 200, 200)  # lane borders
ROADSIDE = (120, 120, 120)  # roadside objects (wireframe)
GROUND = (90, 90, 90)  # ground points
UNLABELLED = (200, 200, 200)  # non-ground points in no detection (noise, rejected)
CLUSTERS = np.array([[230, 159, 0], [86, 180, 233], [0, 158, 115], [240, 228, 66], [0, 114, 178],
                     [213, 94, 0], [204, 121, 167], [170, 170, 255]], dtype=np.uint8)  # points, by detection
DETECTION = (40, 220, 40)  # a detection from a vehicle
CLUTTER = (230, 40, 40)  # a clutter detection
MERGED = (230, 0, 230)  # fitted box of merged fragments
SPLIT = (0, 210, 230)  # fitted box split from a larger cluster
COMPLETED = (240, 210, 40)  # fitted box completed beyond its points
REJECTED = (150, 110, 70)  # objects the selection removed
SENSOR = (80, 170, 255)  # a further sensor's detections (a radar's)
LAYER = (150, 60, 255, 80)  # SVSF boundary layers: translucent violet fill
SHADOW = (90, 90, 140, 110)  # occlusion shadows: faint, thin
EVENT = (255, 0, 150)  # rings marking a run's events (relabel, false track, missed car): hot pink
OBJECT_AS_ROAD = (230, 30, 30)  # ground-segmentation error: an object point called road
ROAD_AS_OBJECT = (230, 0, 230)  # ground-segmentation error: a road point called object
SLOTS = np.array([[0, 114, 178], [230, 159, 0], [0, 158, 115], [204, 121, 167], [86, 180, 233], [240, 228, 66],
                  [148, 103, 189], [140, 86, 75], [23, 190, 207], [188, 189, 34], [227, 119, 194], [255, 187, 120],
                  [152, 223, 138], [174, 199, 232], [197, 176, 213], [196, 156, 148], [219, 219, 141],
                  [158, 218, 229], [247, 182, 210], [57, 59, 121]], dtype=np.uint8)
"""Confirmed tracks, by their diagnostics slot (testbed/recording/slots.py): the track's point, label, velocity,
trail, ellipse and gate in the scene and its lines in the diagnostics plots share the colour; slot k has
``SLOTS[k % 20]``."""
UNSLOTTED = (150, 150, 150)  # tracks never confirmed (tentative): grey
