"""Sensing stage: truth frames -> LiDAR scan -> perception -> detections (plus added clutter), the cars' visibility
and the occlusion-aware P_D a tracker may ask for; ``sense(scenario)`` is the one sensing loop."""
from .frames import (PD_RANGE_STEP_M, STREAMS, TRUCK_BOX_M, SensedFrame, empty_scan, frame_scan, occlusion_pd, pd_scan,
                     perceive_frame, rng_streams, road_map, scan_frame, sense, sense_frame, sense_simulation, sensing_setup, visibility)

__all__ = ["PD_RANGE_STEP_M", "STREAMS", "TRUCK_BOX_M", "SensedFrame", "empty_scan", "frame_scan", "occlusion_pd", "pd_scan", "perceive_frame",
           "rng_streams", "road_map",
           "scan_frame", "sense", "sense_frame", "sense_simulation", "sensing_setup", "visibility"]
