"""Synthetic LiDAR and its processing: scan -> ground removal -> clustering -> vehicle-like detections.

Only this package imports open3d (lazily, see sensors/open3d_loader.py). It does not import highway_env, rerun,
trackers or testbed.
"""

from roadtrack.sensors.boxfit import SHAPES, BoxFit, BoxFitConfig, SizePrior, fit_vehicle_box, shape_class
from roadtrack.sensors.clustering import CLUSTER_METHODS, ClusterConfig, cluster, scan_line_links
from roadtrack.sensors.clutter import clutter_detections, poisson_clutter
from roadtrack.sensors.ground import GROUND_METHODS, GroundConfig, segment_ground
from roadtrack.sensors.lidar import GROUND, LIDAR_PRESETS, LidarConfig, Scan, scan
from roadtrack.sensors.occlusion import CAR_BOX_M, OcclusionConfig, detection_probability, quantised_ranges, shadows
from roadtrack.sensors.perception import (
    COMPLETED,
    FITS,
    MERGED,
    OFF_ROAD,
    PERCEIVE_STAGES,
    REJECT_REASONS,
    REPRESENTATIVES,
    SPLIT,
    Detections,
    PerceptionConfig,
    PerceptionResult,
    Rejected,
    perceive,
)
from roadtrack.sensors.roi import RoadMap

__all__ = [
    "CLUSTER_METHODS",
    "COMPLETED",
    "FITS",
    "GROUND",
    "GROUND_METHODS",
    "LIDAR_PRESETS",
    "MERGED",
    "OFF_ROAD",
    "PERCEIVE_STAGES",
    "REJECT_REASONS",
    "REPRESENTATIVES",
    "SHAPES",
    "SPLIT",
    "BoxFit",
    "BoxFitConfig",
    "ClusterConfig",
    "Detections",
    "GroundConfig",
    "LidarConfig",
    "OcclusionConfig",
    "PerceptionConfig",
    "PerceptionResult",
    "Rejected",
    "RoadMap",
    "Scan",
    "SizePrior",
    "cluster",
    "scan_line_links",
    "clutter_detections",
    "CAR_BOX_M",
    "detection_probability",
    "quantised_ranges",
    "fit_vehicle_box",
    "perceive",
    "poisson_clutter",
    "scan",
    "segment_ground",
    "shadows",
    "shape_class",
]
