"""Synthetic LiDAR and its processing: scan -> ground removal -> clustering -> vehicle-like detections.

Only this package imports open3d (lazily, see sensors/_o3d.py). It does not import highway_env, rerun,
trackers or testbed.
"""

from sensors.clustering import CLUSTER_METHODS, ClusterConfig, cluster
from sensors.clutter import clutter_detections, poisson_clutter
from sensors.ground import GROUND_METHODS, GroundConfig, segment_ground
from sensors.lidar import GROUND, LidarConfig, Scan, scan
from sensors.perception import REPRESENTATIVES, Detections, PerceptionConfig, PerceptionResult, perceive

__all__ = [
    "CLUSTER_METHODS",
    "GROUND",
    "GROUND_METHODS",
    "REPRESENTATIVES",
    "ClusterConfig",
    "Detections",
    "GroundConfig",
    "LidarConfig",
    "PerceptionConfig",
    "PerceptionResult",
    "Scan",
    "cluster",
    "clutter_detections",
    "perceive",
    "poisson_clutter",
    "scan",
    "segment_ground",
]
