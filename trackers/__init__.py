"""roadtrack multi-target trackers: filters (KF, EKF, ...), associators (NN, GNN, PDA, JPDA, ...), track management.

Conventions: state is a value (`s1 = flt.predict(s0, dt)`), models are data (trackers.models), association is
arithmetic on (T, M) arrays, float64, positions first ([px, py, vx, vy, ...]), probabilities in log space.
A tracker is named "<associator>-<filter>" (see trackers.registry). Depends on numpy and scipy only.

Comments cite the papers (README, "Papers") by section and equation, e.g. "thesis (4.61)". Tags after a
citation: [R] reconstructed (the extracted text is garbled or missing, the standard literature form is used),
[I] inferred from the paper's own numbers, [D] a default chosen here where the paper is silent (always a
parameter).
"""

from roadtrack.trackers.association import (ASSOCIATORS, AssociationInput, AssociationParams, AssociatorParams,
                                  global_nearest_neighbour, jpda, nearest_neighbour, pda)
from roadtrack.trackers.box import BoxParams, box_birth, box_update
from roadtrack.trackers.errors import FilterError, JPDAOverflowError, JPDAOverflowWarning
from roadtrack.trackers.filters import FILTERS, ExtendedKalmanFilter, Filter, KalmanFilter, make_filter, pda_covariance
from roadtrack.trackers.gating import (gate, gate_probability, innovations, log_gaussian, mahalanobis2,
                             mahalanobis2_and_log_gaussian)
from roadtrack.trackers.management import ManagementParams, initial_score, score_decide, score_increment
from roadtrack.trackers.models import (ConstantVelocity, CoordinatedTurn, PositionMeasurement, RangeBearing,
                                       RangeBearingRate, cv_noise_gain,
                             cv_process_noise, cv_transition, measurement_noise, position_measurement_matrix)
from roadtrack.trackers.params import ParamError
from roadtrack.trackers.plugins import register_associator, register_filter
from roadtrack.trackers.registry import (PAPER_TRACKERS, WRAPPERS, available_trackers, describe_tracker, make_tracker,
                               named_trackers, parse_tracker_name, plugin_trackers, preset)
from roadtrack.trackers.state import FilterState
from roadtrack.trackers.tracker import ScanRecord, StepInfo, StepResult, Track, Tracker

__all__ = [
    "ASSOCIATORS", "PAPER_TRACKERS", "AssociationInput", "AssociationParams", "AssociatorParams", "BoxParams",
    "ConstantVelocity", "RangeBearingRate", "box_birth", "box_update",
    "CoordinatedTurn", "ExtendedKalmanFilter", "FILTERS", "Filter", "FilterError", "FilterState",
    "JPDAOverflowError", "JPDAOverflowWarning", "KalmanFilter", "ManagementParams", "ParamError",
    "PositionMeasurement", "RangeBearing", "ScanRecord", "StepInfo", "StepResult", "Track", "Tracker", "WRAPPERS",
    "available_trackers", "describe_tracker", "cv_noise_gain", "cv_process_noise", "cv_transition", "gate", "gate_probability",
    "global_nearest_neighbour", "initial_score", "innovations", "jpda", "log_gaussian", "mahalanobis2",
    "mahalanobis2_and_log_gaussian", "make_filter", "make_tracker", "measurement_noise", "named_trackers", "nearest_neighbour",
    "parse_tracker_name", "pda", "plugin_trackers", "pda_covariance", "position_measurement_matrix", "preset", "register_associator", "register_filter", "score_decide",
    "score_increment",
]

from roadtrack.trackers import plugins as _plugins  # noqa: E402 - last: a plug-in may import anything above

_plugins.load_all(WRAPPERS)  # installed filters and associators (entry points roadtrack.filters, roadtrack.associators)
