"""roadtrack multi-target trackers: NCV Kalman filter, NN/GNN/PDA/JPDA association, LLR track management.

Conventions: state is a value (`s1 = flt.predict(s0, dt)`), association is arithmetic on (T, M) arrays,
float64, positions first ([px, py, vx, vy]), probabilities in log space. Depends on numpy and scipy only.
"""

from trackers.association import ASSOCIATORS, AssociationParams, global_nearest_neighbour, jpda, nearest_neighbour, pda
from trackers.errors import FilterError, JPDAOverflowError, JPDAOverflowWarning
from trackers.filters import FILTERS, Filter, KalmanFilter, pda_covariance
from trackers.gating import (gate, gate_probability, innovations, log_gaussian, mahalanobis2,
                             mahalanobis2_and_log_gaussian)
from trackers.management import ManagementParams, decide, initial_score, score_increment
from trackers.models import (MEASUREMENT_DIM, STATE_DIM, cv_noise_gain, cv_process_noise, cv_transition,
                             measurement_noise, position_measurement_matrix)
from trackers.registry import WRAPPERS, available_trackers, make_tracker, parse_tracker_name
from trackers.state import FilterState
from trackers.tracker import StepInfo, StepResult, Track, Tracker, TrackerParams

__all__ = [
    "ASSOCIATORS", "AssociationParams", "FILTERS", "Filter", "FilterError", "FilterState", "JPDAOverflowError",
    "JPDAOverflowWarning", "KalmanFilter", "MEASUREMENT_DIM", "ManagementParams", "STATE_DIM", "StepInfo", "StepResult",
    "Track", "Tracker", "TrackerParams", "WRAPPERS", "available_trackers", "cv_noise_gain", "cv_process_noise",
    "cv_transition", "decide", "gate", "gate_probability", "global_nearest_neighbour", "initial_score", "innovations",
    "jpda", "log_gaussian", "mahalanobis2", "mahalanobis2_and_log_gaussian", "make_tracker", "measurement_noise",
    "nearest_neighbour", "parse_tracker_name", "pda", "pda_covariance", "position_measurement_matrix",
    "score_increment",
]
