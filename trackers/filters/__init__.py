"""Filters. Registry: name -> FilterKind(params dataclass, build function, one-line doc).

Adding a filter = one module (the filter and its parameter dataclass), one line here; the registry
contract tests then run it. `make_filter("kf", sigma_v=1.0)` builds one from keyword parameters;
`build_filter(kind, data, path)` from a scenario table, with dotted-key errors.
"""

from __future__ import annotations

import dataclasses
from typing import Any

from roadtrack.trackers.filters.base import Filter, ModelFilter, pda_covariance
from roadtrack.trackers.filters.gvbl import GVBLSVSF, GVBLParams, build_gvbl
from roadtrack.trackers.filters.imm import IMMFilter, IMMParams, IMMState, build_imm
from roadtrack.trackers.filters.kalman import ExtendedKalmanFilter, KalmanFilter
from roadtrack.trackers.filters.params import EKFParams, FilterKind, ModelParams
from roadtrack.trackers.filters.svsf import SVSF, GCSVSFParams, GeneralisedSVSF, SVSFParams, build_gc_svsf, build_svsf
from roadtrack.trackers.params import ParamError, load


def _kf(p: ModelParams) -> Filter:
    if p.motion != "cv":
        raise ParamError("motion", f"{p.motion!r} is nonlinear; the kf needs 'cv' (use the ekf)")
    return KalmanFilter(p.motion_model(), p.measurement_model())


FILTERS: dict[str, FilterKind] = {
    "kf": FilterKind(ModelParams, _kf, "linear Kalman filter (thesis §1.1-1.2, §4.2)"),
    "svsf": FilterKind(SVSFParams, build_svsf, "standard SVSF, artificial velocity measurements (thesis ch. 2)"),
    "gc-svsf": FilterKind(GCSVSFParams, build_gc_svsf, "generalised-covariance (CM-) SVSF (thesis ch. 3, (4.37))"),
    "gvbl-svsf": FilterKind(GVBLParams, build_gvbl, "GVBL-SVSF: KF gain inside psi_max, SVSF outside (thesis ch. 4)"),
    "ekf": FilterKind(EKFParams, lambda p: ExtendedKalmanFilter(p.motion_model(), p.measurement_model(),
                                                                 p.second_order),
                      "extended Kalman filter, first or second order (thesis (1.11); seed 000 §3)"),
    "imm": FilterKind(IMMParams, lambda p: build_imm(p, FILTERS, build_filter),
                      "interacting multiple model filter over mode filters (thesis §2.3.4)"),
}


def build_filter(kind: str, data: dict, path: str = "filter") -> Filter:
    """Filter `kind` from the parameter table `data`; ParamError naming the dotted key on bad input."""
    if kind not in FILTERS:
        raise ParamError(f"{path}.kind", f"unknown filter {kind!r}; allowed: {', '.join(sorted(FILTERS))}")
    fk = FILTERS[kind]
    p = load(fk.params, data, path)
    try:
        return fk.build(p)
    except ParamError as err:
        raise ParamError(f"{path}.{err.path}", str(err).split(": ", 1)[-1]) from None


def make_filter(kind: str, **params: Any) -> Filter:
    """e.g. make_filter("kf", sigma_v=1.0, sigma_w=0.3)."""
    return build_filter(kind, params, "filter")


def with_measurement(filter_: Filter, model) -> Filter:
    """``filter_`` with the measurement model ``model`` (trackers.models) for one update: the model a sensor's
    detections carry (a radar's range, azimuth and range-rate from that scan's pose). An IMM gets it in every mode.
    A KF given a nonlinear model becomes the first-order EKF, which is the KF for a linear one (thesis (1.11)) [D];
    an EKF keeps its order when the model has ``hessians``. The SVSF family's gains need the measured states
    themselves (a linear position measurement, thesis ch. 2-4): any other model is a one-line ValueError."""
    if model is filter_.measurement:
        return filter_
    if isinstance(filter_, IMMFilter):
        return dataclasses.replace(filter_, filters=tuple(with_measurement(f, model) for f in filter_.filters))
    if isinstance(filter_, KalmanFilter):
        if model.linear:
            return dataclasses.replace(filter_, measurement=model)
        return ExtendedKalmanFilter(filter_.motion, model)
    if isinstance(filter_, ExtendedKalmanFilter):
        return ExtendedKalmanFilter(filter_.motion, model, filter_.second_order and hasattr(model, "hessians"))
    name = type(filter_).__name__
    if not (model.linear and getattr(model, "ndim", None) == filter_.measurement.ndim
            and type(model) is type(filter_.measurement)):
        raise ValueError(f"the {name} takes only its own kind of measurement ({type(filter_.measurement).__name__}), "
                         f"not {type(model).__name__}: use a KF-, EKF- or IMM-based tracker for this sensor")
    if not dataclasses.is_dataclass(filter_) or "measurement" not in {f.name for f in dataclasses.fields(filter_)}:
        raise ValueError(f"the {name} has no measurement field to replace")
    return dataclasses.replace(filter_, measurement=model)


__all__ = ["EKFParams", "ExtendedKalmanFilter", "FILTERS", "Filter", "FilterKind", "GVBLSVSF", "GeneralisedSVSF",
           "IMMFilter", "IMMState", "KalmanFilter", "ModelFilter", "ModelParams", "SVSF", "build_filter", "make_filter",
           "pda_covariance", "with_measurement"]
