"""Filters. Registry: name -> constructor taking keyword parameters.

Adding a filter = one module, one line here; the registry contract tests then run it."""

from trackers.filters.base import Filter, pda_covariance
from trackers.filters.kalman import KalmanFilter

FILTERS = {
    "kf": KalmanFilter,
}

__all__ = ["FILTERS", "Filter", "KalmanFilter", "pda_covariance"]
