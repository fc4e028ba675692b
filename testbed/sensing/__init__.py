"""Sensing stage: truth frames -> LiDAR scan -> perception -> detections (plus added clutter), the cars' visibility
and the occlusion-aware P_D a tracker may ask for, and the scenario's further sensors (a sensor: one module with a
:class:`Sensor`, one line in ``SENSORS``, registry.py); ``sense(scenario)`` is the one sensing loop."""
from .frames import (PD_RANGE_STEP_M, STREAMS, TRUCK_BOX_M, SensedFrame, empty_scan, frame_scan, occlusion_pd, pd_scan,
                     perceive_frame, rng_streams, road_map, scan_frame, sense, sense_frame, sense_simulation, sensing_setup, visibility)
from .registry import SENSOR_GROUP, SENSORS, scenario_sensors, sensor_registry
from .sensor import Measurements, SensingContext, Sensor, SensorReading, table_problem

__all__ = ["Measurements", "PD_RANGE_STEP_M", "SENSORS", "SENSOR_GROUP", "STREAMS", "TRUCK_BOX_M", "SensedFrame", "SensingContext",
           "Sensor", "SensorReading", "empty_scan", "frame_scan", "occlusion_pd", "pd_scan", "perceive_frame",
           "rng_streams", "road_map", "scan_frame", "scenario_sensors", "sense", "sense_frame", "sense_simulation",
           "sensing_setup", "sensor_registry", "table_problem", "visibility"]
