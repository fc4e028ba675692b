"""Multi-target tracker: predict -> gate -> associate -> update -> score -> confirm/delete -> initiate.

Tracks are immutable values; `Tracker.step` maps (tracks, measurements) to new tracks. It draws no
random numbers and reads no clock.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np
from scipy.special import gammaln

from roadtrack.trackers.association.roles import AssociationInput, AssociatorKind, AssociatorParams
from roadtrack.trackers.filters.base import (Filter, batch_layers, batch_predict, batch_predicted_measurements, batch_update,
                                             check_detection_R, identity, pair_covariances, takes_detection_R,
                                             weighted_R, zeros)
from roadtrack.trackers.gating import gate, mahalanobis2_and_log_gaussian
from roadtrack.trackers.initiation import pair_candidates, single_point, two_point
from roadtrack.trackers.management import (ManagementParams, duplicate_counts, initial_score, m_of_n_decide, miss_loss,
                                 position_std, score_decide, score_increment)
from roadtrack.trackers.road import RoadInput, centripetal_input, cross_lane_std, input_shift, lane_pseudo_measurement
from roadtrack.trackers.state import FilterState, derive
from roadtrack.trackers.trackloss.regime import (ROW_FIXED, WINDOW_LOW, RegimeState, advance, alpha_of, assess_rolled,
                                      initial_state, roll_windows, window_holds, window_of_records, window_rows)

PdInput = np.ndarray | float | Callable[[np.ndarray], np.ndarray] | None
CREDIBLE_GATE_ALPHA = 16.0
"""The chi-square threshold [-] at which `max_gate_m2` measures a track's gate (thesis §4.1: alpha = 16, P_G =
0.9997, the default gate): a user's wider association gate does not shorten the tracks' lives."""


@dataclass(frozen=True, eq=False)
class ScanRecord:
    """What one scan told a track: nu_c (m,) combined innovation; S (m, m); n_gated measurements in the gate;
    gate_volume [m^m]; nis = nu_c^T S^-1 nu_c; detected (at least one gated measurement); pd used; d2 (M,) the
    squared Mahalanobis distances of every measurement of the scan (gated or not; the KS regime detector
    re-gates them, trackers.trackloss.regime); root_det = |S|^(1/2) (None: computed from S when needed)."""

    nu_c: np.ndarray
    S: np.ndarray
    n_gated: int
    gate_volume: float
    nis: float
    detected: bool
    pd: float
    d2: np.ndarray = field(default_factory=lambda: np.zeros(0))
    root_det: float | None = None


@dataclass(frozen=True, eq=False)
class Track:
    """id: label (new one per initiation); state: filter state after the last update; score, max_score:
    track LLR score and its running maximum; confirmed; age: scans since birth (1 at birth);
    hits: scans with at least one gated measurement (birth counts); misses_in_a_row: consecutive
    scans without one; unseen_s: time since the last scan with one [s]; candidate: a one-measurement track candidate waiting for a second measurement
    (two-point initiation; id -1, not associated, not reported); history: the last
    max(`history_length`, the regime window) ScanRecords, oldest first; duplicate_scans: scans in a row spent
    on an older track; regime: the KS track regime detector's verdict of the last scan (paper 002): "unknown"
    (history shorter than its window), "tracking", "track-lost" or "ambiguous"; regime_state: its window,
    CI level and last statistics (trackers.trackloss.regime.RegimeState)."""

    id: int
    state: FilterState
    score: float
    max_score: float
    confirmed: bool
    age: int
    hits: int
    misses_in_a_row: int
    candidate: bool = False
    unseen_s: float = 0.0
    history: tuple[ScanRecord, ...] = ()
    duplicate_scans: int = 0
    regime: str = "unknown"
    regime_state: RegimeState | None = None

    def history_array(self, name: str) -> np.ndarray:
        """One ScanRecord field over the history, oldest first: e.g. history_array("n_gated") (L,)."""
        return np.array([getattr(r, name) for r in self.history])


_TRACK_DEFAULTS = {f.name: f.default for f in dataclasses.fields(Track) if f.default is not dataclasses.MISSING}


@dataclass(frozen=True, eq=False)
class StepInfo:
    """Per-step internals for viewers, for the T tracks that existed at the start of the step (input order),
    after prediction: ids (T,) int64, z_hat (T, m), S (T, m, m), gated (T, M) bool, W (T, M), w0 (T,),
    layers (T, m) boundary-layer half widths (NaN without one), diagnostics: name -> (T,) float64 (NIS,
    gated count, gate volume, P_D, the filters' `info` after the update and the associator's extras;
    vector quantities as name_0, name_1, ...); born_from: id of each track started in this step -> index of the
    measurement it was started on (its class, e.g. a truck's, is that detection's)."""

    ids: np.ndarray
    z_hat: np.ndarray
    S: np.ndarray
    gated: np.ndarray
    W: np.ndarray
    w0: np.ndarray
    layers: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    diagnostics: dict[str, np.ndarray] = field(default_factory=dict)
    born_from: dict[int, int] = field(default_factory=dict)


@dataclass(frozen=True, eq=False)
class StepResult:
    """tracks: surviving input tracks (input order) then new tentative tracks (measurement order);
    next_id: first unused label; deleted: tracks deleted in this step (their final state); info: StepInfo."""

    tracks: tuple[Track, ...]
    next_id: int
    deleted: tuple[Track, ...]
    info: StepInfo


@dataclass(frozen=True, eq=False)
class UpdateResult:
    """`Tracker.update` of a further sensor: tracks (the input tracks, input order, states updated) and the StepInfo
    of the update."""

    tracks: tuple[Track, ...]
    info: StepInfo


@dataclass(frozen=True, eq=False)
class _Prediction:
    states: list
    z_hat: np.ndarray  # (T, m)
    S: np.ndarray  # (T, m, m)
    layers: np.ndarray  # (T, m)

    @functools.cached_property
    def logdet(self) -> np.ndarray:
        """ln|S| (T,), computed once for a scan's gate volumes and duplicate test."""
        return np.linalg.slogdet(self.S)[1] if len(self.S) else np.zeros(0)

    @functools.cached_property
    def half_logdet(self) -> np.ndarray:
        """ln|S| / 2 (T,), computed once for both gate volumes of a scan (`gate_volume`)."""
        return 0.5 * self.logdet


def _check_measurements(Z, m: int) -> np.ndarray:
    Z = np.asarray(Z, dtype=np.float64)
    if Z.size == 0:
        return np.zeros((0, m))
    if Z.ndim != 2 or Z.shape[1] != m:
        raise ValueError(f"Z must have shape (M, {m}), got {Z.shape}")
    bad = np.flatnonzero(~np.isfinite(Z).all(axis=1))
    if bad.size:
        raise ValueError(f"Z has non-finite rows {bad.tolist()}")
    return Z


def _record(**fields: Any) -> ScanRecord:
    """A ScanRecord of checked fields without running the frozen dataclass's __init__ (T per scan)."""
    new = object.__new__(ScanRecord)
    new.__dict__.update(fields)
    return new


def _candidate_state(p: np.ndarray, m: int) -> FilterState:
    """A candidate's state: x = [p; 0] (2d,), P = I, e_post = 0 (m,), the values FilterState(...) would hold (read-only
    float64 arrays; P and e_post the shared read-only constants), without its __init__ (many candidates per scan)."""
    d = len(p)
    x = np.zeros(2 * d)
    x[:d] = p
    x.setflags(write=False)
    new = object.__new__(FilterState)
    new.__dict__.update(x=x, P=identity(2 * d), e_post=zeros(m), F=None, info={})
    return new


def _previous(live) -> np.ndarray:
    """The live tracks' bookkeeping before the scan in one pass, (T, 7) float64 columns: score, max_score, confirmed
    (0 / 1), misses_in_a_row, unseen_s, id, duplicate_scans (integers exact as float64)."""
    return np.array([(tr.score, tr.max_score, tr.confirmed, tr.misses_in_a_row, tr.unseen_s, tr.id, tr.duplicate_scans)
                     for tr in live], dtype=np.float64).reshape(len(live), 7)


def _new_track(**fields: Any) -> Track:
    """Track(**fields) without running the frozen dataclass's __init__ (the tracker's births and candidates), the
    fields not given at their defaults."""
    new = object.__new__(Track)
    new.__dict__.update(_TRACK_DEFAULTS)
    new.__dict__.update(fields)
    return new


def _evolve(tr: Track, **fields: Any) -> Track:
    """`dataclasses.replace` for a Track without re-running __init__ (the tracker's per-scan hot path)."""
    new = object.__new__(Track)
    new.__dict__.update(tr.__dict__)
    new.__dict__.update(fields)
    return new


def keep_memory(new: FilterState, old: FilterState) -> FilterState:
    """``new`` with ``old``'s a-posteriori error memory e_post (an IMM state's and each of its modes'): a further
    sensor's update leaves the primary sensor's memory, which is in the primary's measurement space [D]."""
    fields: dict[str, Any] = {"e_post": old.e_post}
    modes = getattr(new, "modes", None)
    if modes is not None and len(modes) == len(getattr(old, "modes", ())):
        fields["modes"] = tuple(keep_memory(m, o) for m, o in zip(modes, old.modes))
    return derive(new, **fields)


def _window(tr: Track, state: RegimeState, capacity: int) -> np.ndarray | None:
    """The track's rolled KS window before this scan: its state's if that holds the last min(len(history),
    capacity) scans, else rebuilt from the history (a track made outside Tracker.step); None before any scan."""
    length = min(len(tr.history), capacity)
    w = state.window
    if w is not None and w.shape == (capacity, ROW_FIXED + WINDOW_LOW) and window_holds(w, length):
        return w
    return window_of_records(tr.history[len(tr.history) - length:], WINDOW_LOW, capacity) if length else None


def gate_volume(S: np.ndarray, alpha: float, half_logdet: np.ndarray | None = None) -> np.ndarray:
    """V = c_m alpha^(m/2) sqrt|S| (T,), c_m the unit-ball volume (thesis §4.1 [R]; c_2 = pi); half_logdet (T,):
    ln|S| / 2 when the caller has it (a scan's `_Prediction.half_logdet`)."""
    m = S.shape[-1]
    log_cm = 0.5 * m * math.log(math.pi) - float(gammaln(0.5 * m + 1.0))
    h = half_logdet if half_logdet is not None else 0.5 * np.linalg.slogdet(S)[1]
    return np.exp(log_cm + 0.5 * m * math.log(alpha) + h)  # thesis §4.1: V = c_m alpha^(m/2) |S|^(1/2)


def _expand(name: str, v: Any, T: int, out: dict[str, np.ndarray], t: int) -> None:
    a = np.atleast_1d(np.asarray(v, dtype=np.float64))
    keys = [name] if a.size == 1 else [f"{name}_{i}" for i in range(a.size)]
    for k, x in zip(keys, a.reshape(-1)):
        out.setdefault(k, np.full(T, np.nan))[t] = x


def info_diagnostics(states: list, out: dict[str, np.ndarray]) -> None:
    """The filters' `info` of T states into `out` as (T,) float64 columns, vector entries as name_0, name_1, ...,
    NaN where a track has no such entry (in the order the entries first appear over the tracks): entry by entry
    at once over the tracks that have it, or track by track if an entry's size differs between tracks."""
    T = len(states)
    by_name: dict[str, tuple[list[int], list]] = {}
    for t, s in enumerate(states):
        for name, v in s.info.items():
            rows = by_name.get(name)
            if rows is None:
                by_name[name] = rows = ([], [])
            rows[0].append(t)
            rows[1].append(v)
    cols = []
    for name, (rows, values) in by_name.items():
        try:
            cols.append((name, rows, np.array(values, dtype=np.float64).reshape(len(rows), -1)))
        except ValueError:  # sizes differ between tracks: their columns interleave, as the per-track loop makes them
            for t, s in enumerate(states):
                for key, v in s.info.items():
                    _expand(key, v, T, out, t)
            return
    for name, rows, a in cols:
        keys = [name] if a.shape[1] == 1 else [f"{name}_{i}" for i in range(a.shape[1])]
        for k, col in zip(keys, a.T):
            out.setdefault(k, np.full(T, np.nan))[rows] = col


@dataclass(frozen=True)
class Tracker:
    """A tracker = filter (updater) + associator + manager (confirmer/deleter and initiator), each with typed
    parameters. Build one by name with `trackers.make_tracker`. `step` is the pipeline:
    predict -> gate -> associate -> update -> manage -> initiate."""

    filter: Filter
    associator: AssociatorKind
    association: AssociatorParams = field(default_factory=AssociatorParams)
    management: ManagementParams = field(default_factory=ManagementParams)
    manager: str = "score"
    name: str = ""

    def kinematics(self, tracks: tuple[Track, ...]) -> tuple[np.ndarray, np.ndarray]:
        """Position-velocity estimates of `tracks` from each filter's output: kin (T, 2d) [p; v] and its
        covariance (T, 2d, 2d), d the number of position entries of the filter's motion model."""
        return self.state_kinematics([tr.state for tr in tracks])

    @functools.cached_property
    def _kinematic_index(self) -> tuple[np.ndarray, bool]:
        """The state entries [p; v] (2d,) of the filter's motion model (read-only), and whether they are the whole
        state in order (a 2-D constant-velocity state [px, py, vx, vy]: kinematics are the states themselves)."""
        mot = self.filter.motion
        idx = np.array(list(mot.position) + list(mot.velocity))
        idx.setflags(write=False)
        return idx, bool(np.array_equal(idx, np.arange(idx.size)))

    def state_kinematics(self, states: list, cov: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
        """`kinematics` of filter states (T of them): kin (T, 2d) [p; v], cov (T, 2d, 2d) (None with ``cov`` False:
        the callers that read positions and velocities only skip stacking the covariances)."""
        idx, in_order = self._kinematic_index
        if not states:
            return np.zeros((0, idx.size)), np.zeros((0, idx.size, idx.size)) if cov else None
        out = [self.filter.output(s) for s in states]
        n = {x.size for x, _ in out}
        if len(n) != 1:  # outputs of several sizes: track by track
            return (np.array([x[idx] for x, _ in out]),
                    np.array([P[np.ix_(idx, idx)] for _, P in out]) if cov else None)
        X = np.array([x for x, _ in out])
        whole = in_order and X.shape[1] == idx.size  # [p; v] is the state: no gather
        if not cov:
            return (X if whole else X[:, idx]), None
        P = np.array([P for _, P in out])
        return (X, P) if whole else (X[:, idx], P[:, idx][:, :, idx])

    @property
    def pg(self) -> float:
        """Gate probability P_G: the associator's `pg`, or F_chi2_m(gate_alpha) when it is None."""
        return self.association.gate_probability(self.filter.measurement.ndim)

    def step(self, tracks: tuple[Track, ...], Z: np.ndarray, dt: float, next_id: int,
             pd: PdInput = None, road: RoadInput | None = None, R: np.ndarray | None = None) -> StepResult:
        """One scan. tracks: current tracks; Z (M, m) measurements; dt [s] since the last scan; next_id: label
        for the next new track; pd: detection probability per track, as an array (T,) over the non-candidate
        tracks in input order, or a function of their predicted measurements (T, m) -> (T,) (occlusion-aware
        P_D), or None for the associator's pd; road: the lane map as a function of positions (trackers.road) or
        None (no road-map aid; the life bounds max_position_std_m and max_unseen_s); R (M, m, m): each
        measurement's own covariance, used in the gate, the likelihood, the update and initiation when the filter's
        measurement model asks for it (``per_detection``, e.g. the filter key detection_R) and its update takes it
        (trackers.filters.base.takes_detection_R), else ignored (the model's fixed R). Raises ValueError on
        non-finite Z or dt, or an R that is not finite, symmetric and positive definite, before any update."""
        Z, Rz, dt = self._inputs(Z, R, dt)
        candidates = tuple(tr for tr in tracks if tr.candidate)
        live = tuple(tr for tr in tracks if not tr.candidate)
        pred = self._predict(live, dt, road)
        pdt = self._pd(pd, pred)
        live, pred, pdt, too_wide = self._drop_wide(live, pred, pdt, road)
        inp = self._gate(pred, Z, pdt, Rz)
        W, w0, extra = self._associate(inp)
        states = batch_update(self.filter, pred.states, inp.nu, W, w0, Rz, inp.log_lik)
        if road is not None and self.management.road_lane_keeping:
            states = self._keep_lanes(live, states, W, road)
        survivors, deleted, diag = self._manage(live, states, inp, W, w0, pred, dt, road, Rz)
        deleted = too_wide + deleted
        for k, v in extra.items():
            diag[k] = np.asarray(v, dtype=np.float64)
        births, next_id, born_from = self._initiate(candidates, live, Z, inp, dt, next_id, pred, Rz)
        info = StepInfo(ids=np.array([tr.id for tr in live], dtype=np.int64).reshape(len(live)), z_hat=pred.z_hat,
                        S=pred.S, gated=inp.gated, W=W, w0=w0, layers=pred.layers, diagnostics=diag,
                        born_from=born_from)
        return StepResult(tracks=tuple(survivors + births), next_id=int(next_id), deleted=tuple(deleted), info=info)

    def with_measurement(self, model, **association: Any) -> "Tracker":
        """This tracker with the measurement model ``model`` (trackers.models; e.g. a radar's RangeBearingRate at
        the scan's pose: detections carry their model) in its filter (trackers.filters.with_measurement) and the
        associator keys ``association`` replaced (pd, clutter_density in the model's measurement-space units,
        gate_alpha for its dimension). ValueError (one line) for a filter that cannot take the model."""
        from roadtrack.trackers.filters import with_measurement

        flt = with_measurement(self.filter, model)
        assoc = dataclasses.replace(self.association, **association) if association else self.association
        if flt is self.filter and assoc is self.association:
            return self
        return dataclasses.replace(self, filter=flt, association=assoc)

    def update(self, tracks: tuple[Track, ...], Z: np.ndarray, dt: float, pd: PdInput = None,
               R: np.ndarray | None = None) -> UpdateResult:
        """A further sensor's detections Z (M, m) at ``dt`` [s] after the tracks' last scan (0: the same instant):
        predict, gate, associate and update only, for sequential fusion in time order (Bar-Shalom's sequential
        multi-sensor update) [D]. The primary sensor's `step` keeps the life cycle (scores, confirmation,
        deletion, initiation, the KS regime, which are in its measurement space); candidates are left as they
        are; each state keeps the primary's a-posteriori error memory e_post (the SVSF family's, in the primary's
        measurement space) [D]. Build the tracker for the sensor with `with_measurement`. pd and R as in
        `step`. Returns the tracks in input order (nothing deleted or born) and the StepInfo of the update."""
        Z, Rz, dt = self._inputs(Z, R, dt)
        idx = [i for i, tr in enumerate(tracks) if not tr.candidate]
        live = tuple(tracks[i] for i in idx)
        pred = self._predict(live, dt)
        inp = self._gate(pred, Z, self._pd(pd, pred), Rz)
        W, w0, extra = self._associate(inp)
        states = batch_update(self.filter, pred.states, inp.nu, W, w0, Rz, inp.log_lik)
        out = list(tracks)
        for i, tr, s in zip(idx, live, states):
            out[i] = _evolve(tr, state=keep_memory(s, tr.state))
        diag = {"n_gated": inp.gated.sum(axis=1).astype(np.float64), "w0": np.asarray(w0, dtype=np.float64),
                **{k: np.asarray(v, dtype=np.float64) for k, v in extra.items()}}
        info = StepInfo(ids=np.array([tr.id for tr in live], dtype=np.int64).reshape(len(live)), z_hat=pred.z_hat,
                        S=pred.S, gated=inp.gated, W=W, w0=w0, layers=pred.layers, diagnostics=diag)
        return UpdateResult(tracks=tuple(out), info=info)

    # ------------------------------------------------------------------ roles
    def _inputs(self, Z: np.ndarray, R: np.ndarray | None, dt: float) -> tuple[np.ndarray, np.ndarray | None, float]:
        """The checked measurements Z (M, m), their own covariances when the filter takes them (else None) and dt
        [s]; ValueError on non-finite Z or dt, or a bad R."""
        Z = _check_measurements(Z, self.filter.measurement.ndim)
        Rz = None
        if R is not None and takes_detection_R(self.filter):
            Rz = check_detection_R(R, len(Z), self.filter.measurement.ndim)
        dt = float(dt)
        if not math.isfinite(dt) or dt < 0:
            raise ValueError(f"dt must be finite and >= 0, got {dt}")
        return Z, Rz, dt

    def _predict(self, live: tuple[Track, ...], dt: float, road: RoadInput | None = None) -> _Prediction:
        flt, m = self.filter, self.filter.measurement.ndim
        states = batch_predict(flt, [tr.state for tr in live], dt)
        if road is not None and self.management.road_curvature and live and dt > 0 and hasattr(flt, "shift_many"):
            kin, _ = self.state_kinematics([tr.state for tr in live], cov=False)
            if kin.shape[1] == 4:  # the road input of trackers.road, at the previous estimates
                shift = input_shift(centripetal_input(road, kin[:, :2], kin[:, 2:]), dt)
                states = flt.shift_many(states, shift, self.management.road_curvature_spread)
        z_hat, S = batch_predicted_measurements(flt, states)
        T = len(live)
        return _Prediction(states, z_hat.reshape(T, m), S.reshape(T, m, m), batch_layers(flt, states, m))

    def _drop_wide(self, live, pred: _Prediction, pdt: np.ndarray, road: RoadInput | None):
        """With a road and `max_gate_m2`: the tracks whose predicted gate exceeds it leave before association (a
        track is deleted before its gate passes the bound, not after); returns the rest and the dropped."""
        mp = self.management
        if (road is None or not mp.road_life or mp.max_gate_m2 is None or not live
                or not self.filter.measurement.linear):  # a nonlinear model's gate (a radar's) is not in m^2
            return live, pred, pdt, []
        wide = gate_volume(pred.S, CREDIBLE_GATE_ALPHA, pred.half_logdet) > mp.max_gate_m2
        if not wide.any():
            return live, pred, pdt, []
        keep = np.flatnonzero(~wide)
        kept = _Prediction([pred.states[t] for t in keep], pred.z_hat[keep], pred.S[keep], pred.layers[keep])
        gone = [_evolve(live[t], state=pred.states[t], age=live[t].age + 1) for t in np.flatnonzero(wide)]
        return tuple(live[t] for t in keep), kept, pdt[keep], gone

    def _pd(self, pd: PdInput, pred: _Prediction) -> np.ndarray:
        T = len(pred.states)
        if pd is None:
            return np.full(T, self.association.pd)
        values = pd(pred.z_hat) if callable(pd) else pd
        out = np.broadcast_to(np.asarray(values, dtype=np.float64), (T,)).copy()
        if not ((out >= 0.0) & (out <= 1.0)).all():
            raise ValueError("per-track detection probabilities must lie in [0, 1]")
        return out

    def _gate(self, pred: _Prediction, Z: np.ndarray, pdt: np.ndarray, R: np.ndarray | None) -> AssociationInput:
        """Innovations, distances and likelihoods of every (track, measurement) pair; with the measurements' own
        covariances R (M, m, m), S_tj = S_t - R_fixed + R_j (`pair_covariances`)."""
        meas = self.filter.measurement
        nu = meas.residual(Z[None, :, :], pred.z_hat[:, None, :])  # §4.1 / (4.15) innovation z - h(x_pred)
        S_pairs = None if R is None else pair_covariances(pred.S, R, meas.R)  # §4.1 S = H P H^T + R_j
        d2, log_lik = mahalanobis2_and_log_gaussian(nu, pred.S if S_pairs is None else S_pairs)
        alpha = self.association.gate_alpha
        return AssociationInput(log_lik=log_lik, gated=gate(d2, alpha), d2=d2, nu=nu, S=pred.S, pd=pdt, pg=self.pg,
                                gate_volume=gate_volume(pred.S, alpha, pred.half_logdet) if len(pred.S) else np.zeros(0),
                                layers=pred.layers, S_pairs=S_pairs)

    def _associate(self, inp: AssociationInput) -> tuple[np.ndarray, np.ndarray, dict]:
        out = self.associator.run(inp, self.association)
        W, w0 = np.asarray(out[0], dtype=np.float64), np.asarray(out[1], dtype=np.float64)
        T, M = inp.gated.shape
        if W.shape != (T, M) or w0.shape != (T,):
            raise ValueError(f"associator returned W {W.shape} and w0 {w0.shape}, expected ({T}, {M}) and ({T},)")
        return W, w0, (out[2] if len(out) > 2 else {})

    def _score(self, score: np.ndarray, confirmed: np.ndarray, inp: AssociationInput, W: np.ndarray) -> np.ndarray:
        """Scores after this scan from the scores score (T,) and confirmed flags (T,) before it, with the caller's
        per-track P_D. A tentative track's scan with a gated measurement uses at least the nominal P_D [D] (a
        detection is full evidence whatever the caller's P_D says), and so does a missed one with `tentative_pd`
        "nominal" (a miss in a sensor shadow then costs as a miss in view); with "misses" (default) a missed scan uses
        the caller's P_D, which prices it: nothing in a shadow. Per scan this is the P_D in [caller's, nominal] most
        favourable to the target (a generalised likelihood ratio)."""
        lift = ~confirmed
        if self.management.tentative_pd == "misses":
            lift &= inp.gated.any(axis=1)
        pd = np.where(lift, np.maximum(inp.pd, self.association.pd), inp.pd)
        lam = self.association.clutter_density
        if self.management.score_mode == "gate":
            return score + score_increment(inp.log_lik, inp.gated, pd, inp.pg, lam)  # §7.2 / (1.35)
        # "exclusive" [D]: L_ti weighted by rho_ti = 1 - sum_{s != t} W[s, i] (no other track claims z_i)
        rho = np.clip(1.0 - (W.sum(axis=0)[None, :] - W), 0.0, 1.0)
        with np.errstate(divide="ignore"):
            return score + score_increment(inp.log_lik + np.log(rho), inp.gated & (rho > 0.0), pd, inp.pg, lam)

    def _keep_lanes(self, live, states: list, W: np.ndarray, road: RoadInput) -> list:
        """Lane keeping (trackers.road): the confirmed tracks the scan did not update (association weights W (T, M)
        summing to less than 1/2) get the pseudo-measurement 'in the nearest lane' (filters with a
        `pseudo_update_many` hook only)."""
        flt = self.filter
        missed = (W.sum(axis=1) < 0.5).tolist()
        idx = [t for t, tr in enumerate(live) if tr.confirmed and missed[t]]
        if not idx or not hasattr(flt, "pseudo_update_many"):
            return states
        kin, _ = self.state_kinematics([states[t] for t in idx], cov=False)
        if kin.shape[1] != 4:  # the lane map is 2-D: [px, py, vx, vy] only
            return states
        h, y, r = lane_pseudo_measurement(road, kin[:, :2])
        steady = np.abs(np.einsum("tk,tk->t", h, kin[:, 2:])) <= self.management.lane_keeping_max_cross_mps
        steady &= y * y <= 3.0 * r  # on the road: within its lane's half width (r = w^2 / 3); not off-road objects
        idx = [t for t, ok in zip(idx, steady) if ok]  # not while changing lanes
        out = list(states)
        if idx:
            for t, s in zip(idx, flt.pseudo_update_many([states[t] for t in idx], h[steady], y[steady], r[steady])):
                out[t] = s
        return out

    def _manage(self, live, states, inp: AssociationInput, W, w0, pred: _Prediction, dt: float,
                road: RoadInput | None = None, R: np.ndarray | None = None):
        mp, T = self.management, len(live)
        hit = inp.gated.any(axis=1)
        prev = _previous(live)
        was_confirmed = prev[:, 2] != 0.0
        score = self._score(prev[:, 0], was_confirmed, inp, W)
        max_score = np.maximum(prev[:, 1], score)
        misses = np.where(hit, 0, prev[:, 3].astype(np.int64) + 1)  # misses in a row
        unseen = np.where(hit, 0.0, prev[:, 4] + dt)
        records, diag, root_det = self._records(states, inp, W, hit, R)
        if self.manager == "m_of_n":
            det, known = self._windows(live, hit)
            confirmed, delete = m_of_n_decide(det, misses, was_confirmed, mp, known)
        else:  # the drop follows the nominal P_D: a track whose caller-given P_D is 0 is not deleted for it
            drop = mp.deletion_drop(self.association.pd, inp.pg)
            confirmed, delete = score_decide(score, max_score, was_confirmed, mp, drop,
                                             miss_loss(self.association.pd, inp.pg))
        kin, cov = self.state_kinematics(states)  # one pass over the filters' outputs for both life rules
        d = kin.shape[1] // 2
        std = position_std(cov[:, :d, :d])
        diag["position_std"] = std
        if road is None or not mp.road_life or d != 2:
            delete = delete | self._beyond_bounds(std, unseen)
        else:
            delete = delete | self._not_credible(kin[:, :2], cov[:, :2, :2], pred, W.sum(axis=1) >= 0.5, confirmed,
                                                 road)
        dup = duplicate_counts(pred.z_hat, pred.S, inp.gated, confirmed & was_confirmed, prev[:, 5].astype(np.int64),
                               prev[:, 6].astype(np.int64), mp.merge_d2, misses, pred.logdet)
        keep = max(mp.history_length, mp.regime_config.longest)
        histories = [(tr.history + (records[t],))[-keep:] for t, tr in enumerate(live)]
        regimes = self._regimes(live, histories, inp.d2, diag, root_det, inp.pd)
        lost = np.array([r.label == "track-lost" for r in regimes], dtype=bool).reshape(T)
        if mp.deletion == "ks":  # paper 002: a confirmed track goes when its KS regime is track-lost
            delete = np.where(confirmed, lost, delete)
        elif mp.deletion == "manager+ks":
            delete = delete | lost
        delete = delete | (dup >= mp.merge_scans)
        survivors, deleted = [], []
        for tr, s, sc, ms, c, h, mi, un, du, hi, rg, de in zip(
                live, states, score.tolist(), max_score.tolist(), confirmed.tolist(), hit.tolist(), misses.tolist(),
                unseen.tolist(), dup.tolist(), histories, regimes, delete.tolist()):
            new = _evolve(tr, state=s, score=sc, max_score=ms, confirmed=c, age=tr.age + 1, hits=tr.hits + int(h),
                          misses_in_a_row=mi, unseen_s=un, duplicate_scans=du, history=hi, regime=rg.label,
                          regime_state=rg)
            (deleted if de else survivors).append(new)
        diag["score"] = score
        diag["w0"] = np.asarray(w0, dtype=np.float64)
        return survivors, deleted, diag

    def _beyond_bounds(self, std: np.ndarray, unseen: np.ndarray) -> np.ndarray:
        """(T,) tracks past the life bounds [D]: position std above max_position_std_m or unseen for longer
        than max_unseen_s (module trackers.management), whatever their P_D."""
        mp = self.management
        out = np.zeros(len(std), dtype=bool)
        if mp.max_position_std_m is not None:
            out |= std > mp.max_position_std_m
        if mp.max_unseen_s is not None:
            out |= unseen > mp.max_unseen_s + 1e-9
        return out

    def _not_credible(self, xy: np.ndarray, P_pos: np.ndarray, pred: _Prediction, updated: np.ndarray,
                      confirmed: np.ndarray, road: RoadInput) -> np.ndarray:
        """(T,) tracks no longer credible for re-acquisition with a road map [D] (trackers.management, "Life with
        a road map"): cross-lane std above max_position_std_m or, not updated by the scan
        (``updated`` (T,): association weights summing to 1/2 or more), another confirmed track's predicted
        position within credible_d2 under the track's own S. xy (T, 2) [m], P_pos (T, 2, 2) [m^2]: the updated
        positions and their covariances."""
        mp, T = self.management, len(xy)
        out = np.zeros(T, dtype=bool)
        if T == 0:
            return out
        if mp.max_position_std_m is not None:
            out |= cross_lane_std(road, xy, P_pos) > mp.max_position_std_m
        others = np.flatnonzero(confirmed)
        hidden = np.flatnonzero(~updated)  # only a track the scan did not update can fail this test
        if mp.credible_d2 is not None and others.size > 1 and hidden.size and self.filter.measurement.linear:
            z = pred.z_hat[:, :2]  # z = position
            d = z[hidden, None, :] - z[None, others, :]  # (H, C, 2)
            d2 = np.einsum("tck,tck->tc", d, np.linalg.solve(pred.S[hidden, None, :2, :2], d[..., None])[..., 0])
            d2[others[None, :] == hidden[:, None]] = np.inf  # not itself
            out[hidden] |= (d2 <= mp.credible_d2).any(axis=1)
        return out

    def _regimes(self, live, histories, d2: np.ndarray, diag: dict[str, np.ndarray], root_det: np.ndarray,
                 pd: np.ndarray) -> list[RegimeState]:
        """Each track's KS regime after this scan (paper 002 §V) from its rolled window (this scan's row from the
        new record: |S|^(1/2) root_det (T,), P_D pd (T,) and d2 (T, M), the distances of every measurement), with the
        manager's clutter density for the
        regime (default: the associator's) and the per-scan P_D; one batch per window length. The same tests as
        on the histories (trackers.trackloss.regime.assess_rolled). Adds the diagnostics ks_regime (1 tracking,
        0 ambiguous, -1 track-lost), ks_D_T, ks_D_L, ks_d_n, ks_n (NaN while unknown)."""
        mp, T, nz = self.management, len(live), self.filter.measurement.ndim
        cfg = mp.regime_config
        lam = mp.regime_clutter_density or self.association.clutter_density
        rows = window_rows(root_det.reshape(T), pd.reshape(T), d2, WINDOW_LOW)  # the new records' row
        cap = cfg.longest
        states, old, ready = [], [], []
        for tr, h in zip(live, histories):
            s = tr.regime_state or initial_state(cfg)
            states.append(s)
            old.append(_window(tr, s, cap))
            ready.append(min(len(h), cap) >= s.n)
        windows = roll_windows(old, rows, cap)  # (T, cap, 3 + k)
        out = [None if ok else advance(s, None, cfg, w) for s, w, ok in zip(states, windows, ready)]
        for n in sorted({s.n for s, ok in zip(states, ready) if ok}):  # one batch per window length (adaptive: several)
            group = [t for t in range(T) if ready[t] and states[t].n == n]
            hs = [histories[t] for t in group]
            tests = assess_rolled(windows[np.array(group), cap - n:], lam, nz,
                                  [alpha_of(states[t], cfg) for t in group],
                                  lambda i, j, hs=hs, n=n: hs[i][len(hs[i]) - n + j].d2)
            for t, test in zip(group, tests):
                out[t] = advance(states[t], test, cfg, windows[t])
        code = {"tracking": 1.0, "ambiguous": 0.0, "track-lost": -1.0}
        rows = [(code[r.label], r.last.D_T, r.last.D_L, r.last.d_n, r.last.n) if r.label != "unknown"
                else (np.nan,) * 5 for r in out]
        cols = np.array(rows, dtype=np.float64).reshape(T, 5)
        for i, name in enumerate(("ks_regime", "ks_D_T", "ks_D_L", "ks_d_n", "ks_n")):
            diag[name] = cols[:, i].copy()
        return out

    def _windows(self, live, hit: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """m-of-n windows: detected and known (T, n) flags of the last n scans, newest last. Scans before the
        history (the birth scans, `hits` at birth) count as detections; scans before birth are unknown."""
        n, T = self.management.confirm_n, len(live)
        det = np.zeros((T, n), dtype=bool)
        known = np.zeros((T, n), dtype=bool)
        for t, tr in enumerate(live):
            flags = [True] * max(tr.age - len(tr.history), 0) + [r.detected for r in tr.history] + [bool(hit[t])]
            flags = flags[-n:]
            det[t, n - len(flags):] = flags
            known[t, n - len(flags):] = True
        return det, known

    def _records(self, states, inp: AssociationInput, W, hit, R: np.ndarray | None = None
                 ) -> tuple[list[ScanRecord], dict[str, np.ndarray], np.ndarray]:
        """Each track's ScanRecord, the per-track diagnostics and the records' |S|^(1/2) (T,). With the measurements'
        own covariances R (M, m, m), a track's record S (and its NIS) uses the association-weighted R of its
        measurements (`weighted_R`)."""
        T = len(states)
        nu_c = np.einsum("tj,tjm->tm", W, inp.nu) if T else np.zeros((0, inp.nu.shape[-1]))
        S = inp.S
        if R is not None and T and len(R):
            used = W.sum(axis=1) > 0.0
            S = np.where(used[:, None, None], S - self.filter.measurement.R + weighted_R(R, W), S)
        nis = np.einsum("tm,tm->t", nu_c, np.linalg.solve(S, nu_c[..., None])[..., 0]) if T else np.zeros(0)
        n_gated = inp.gated.sum(axis=1)
        root_det = np.sqrt(np.linalg.det(S)) if T else np.zeros(0)  # once per record, for the KS windows
        records = [_record(nu_c=a, S=b, n_gated=c, gate_volume=d, nis=e, detected=f, pd=g, d2=h, root_det=i)
                   for a, b, c, d, e, f, g, h, i in zip(nu_c, S, n_gated.tolist(), inp.gate_volume.tolist(), nis.tolist(),
                                                        hit.tolist(), inp.pd.tolist(), inp.d2, root_det.tolist())]
        diag = {"nis": nis, "n_gated": n_gated.astype(np.float64), "gate_volume": inp.gate_volume.astype(np.float64),
                "pd": inp.pd.astype(np.float64)}
        info_diagnostics(states, diag)
        return records, diag, root_det

    def _claims(self, live, Z: np.ndarray, inp: AssociationInput, pred: _Prediction) -> np.ndarray:
        """(T, M) the gated measurements each live track claims (they start no new track; trackers.management,
        "Initiation"): in the gate of a track whose gate std is at most `claim_std_m`, or that is young and was
        detected in the last scan (its S is wide), within `claim_d2` of its prediction (a measurement it would take
        for its own car's, not one of the car in the next lane that its wide gate reaches); or within
        `claim_radius_m` of its predicted position, whatever its gate."""
        mp, claims = self.management, inp.gated
        if mp.claim_std_m is None or not len(pred.S):
            return claims
        fresh = np.array([tr.misses_in_a_row == 0 and tr.age <= mp.claim_age_scans for tr in live],
                         dtype=bool).reshape(len(live))
        owns = ((position_std(pred.S) <= mp.claim_std_m) | fresh)[:, None]
        if mp.claim_d2 is not None:
            owns = owns & (inp.d2 <= mp.claim_d2)  # [D] the claim test: the 99 % point of chi^2_2 by default
        if mp.claim_radius_m is not None and Z.size:
            d = pred.z_hat[:, None, :2] - Z[None, :, :2]
            owns = owns | (np.einsum("tmk,tmk->tm", d, d) <= mp.claim_radius_m**2)  # (T, M)
        return claims & owns

    def _initiate(self, candidates, live, Z: np.ndarray, inp: AssociationInput, dt: float, next_id: int,
                  pred: _Prediction, R: np.ndarray | None = None):
        """New tentative tracks from measurements no live track claims (§7.2; `_claims` [D]): at once ("single") or from a candidate of the previous scan paired within reach ("two_point",
        [D]). A candidate keeps its position in x[:d]. With the measurements' own covariances R (M, m, m) a new
        track's position covariance is its measurement's."""
        mp, flt, meas = self.management, self.filter, self.filter.measurement
        lam, pd = self.association.clutter_density, self.association.pd
        score0 = initial_score(mp, lam, pd)
        free = np.flatnonzero(~self._claims(live, Z, inp, pred).any(axis=0))
        out, used, born_from = [], set(), {}

        def new(state, score, label, age, candidate=False):
            return _new_track(id=label, state=state, score=score, max_score=score, confirmed=False, age=age,
                              hits=age, misses_in_a_row=0, candidate=candidate)

        if mp.initiation == "single":
            for j in free:
                out.append(new(flt.initial_state(*single_point(Z[j], meas, mp.v_max, None if R is None else R[j])), score0, int(next_id), 1))
                born_from[int(next_id)] = int(j)
                next_id += 1
            return out, next_id, born_from
        positions = [meas.position_of(Z[j]) if R is None else (Z[j], R[j]) for j in free]
        if dt > 0 and candidates and free.size:
            d = len(positions[0][0])
            sigma = math.sqrt(float(np.max(np.linalg.eigvalsh(positions[0][1]))))
            reach = mp.v_max * dt + 3.0 * math.sqrt(2.0) * sigma  # [D] two-point reach v_max dt + 3 sqrt(2) sigma_w
            ball = math.exp(0.5 * d * math.log(math.pi) - float(gammaln(0.5 * d + 1.0))) * reach ** d
            inc = math.log(pd / ball / lam)  # §7.2-style LLR of the second point: ln(P_D g / lambda), g = 1 / ball
            C = np.array([c.state.x[:d] for c in candidates])
            for c, f in pair_candidates(C, np.array([p for p, _ in positions]), reach):
                used.add(f)
                x0, P0 = two_point(C[c], Z[free[f]], dt, meas, None if R is None else R[free[f]])
                out.append(new(flt.initial_state(x0, P0), score0 + inc, int(next_id), 2))
                born_from[int(next_id)] = int(free[f])
                next_id += 1
        for f, (p, Rp) in enumerate(positions):
            if f not in used:
                out.append(new(_candidate_state(p, meas.ndim), score0, -1, 1, candidate=True))
        return out, next_id, born_from
