"""Parameter dataclasses shared by the filters: the motion and measurement models of a single-model filter,
and the registry entry type. Kept apart from the registry so filter modules can subclass ModelParams."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

from roadtrack.trackers.filters.base import Filter
from roadtrack.trackers.models import ConstantVelocity, CoordinatedTurn, PositionMeasurement
from roadtrack.trackers.params import NON_NEGATIVE, POSITIVE, param


@dataclass(frozen=True)
class ModelParams:
    """Motion and measurement model parameters shared by every single-model filter."""

    motion: str = param("cv", "motion model: near-constant velocity or coordinated turn (thesis §1.1, §1.3)",
                        choices=("cv", "ct"))
    sigma_v: float = param(2.0, "white-acceleration std [m/s^2]", check=NON_NEGATIVE)
    sigma_omega: float = param(0.02, "ct: turn-rate noise std [rad/s^2] (thesis §1.3 [D])", check=NON_NEGATIVE)
    omega_std0: float = param(0.1, "ct: prior std of a new track's turn rate [rad/s]", check=POSITIVE)
    sigma_w: float = param(0.3, "position measurement noise std [m]", check=POSITIVE)
    detection_R: bool = param(False, "use each detection's own covariance (perception's range-aware R, Frame.R) in "
                              "the gate, the likelihood, the update and initiation when the frame gives one, "
                              "sigma_w otherwise (off by default: docs/trackers.md, 'Per-detection covariances')")

    def motion_model(self):
        if self.motion == "ct":
            return CoordinatedTurn(self.sigma_v, self.sigma_omega, self.omega_std0)
        return ConstantVelocity(self.sigma_v)

    def measurement_model(self):
        return PositionMeasurement(self.sigma_w, per_detection=self.detection_R)


@dataclass(frozen=True)
class EKFParams(ModelParams):
    second_order: bool = param(False, "add the second-order terms of h (seed 000 §3)")


@dataclass(frozen=True)
class FilterKind:
    params: type
    build: Callable[[Any], Filter]
    doc: str
