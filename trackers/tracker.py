"""Multi-target tracker: predict -> gate -> associate -> update -> score -> confirm/delete -> initiate.

Tracks are immutable values; `Tracker.step` maps (tracks, measurements) to new tracks. It draws no
random numbers and reads no clock.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields, replace
from typing import Callable

import numpy as np
from scipy.optimize import linear_sum_assignment

from trackers.association.params import OVERFLOW_MODES, AssociationParams
from trackers.filters.base import Filter
from trackers.gating import gate, gate_probability, innovations, mahalanobis2_and_log_gaussian
from trackers.management import ManagementParams, decide, initial_score, score_increment
from trackers.models import MEASUREMENT_DIM
from trackers.state import FilterState

SCORE_MODES = ("gate", "exclusive")
INITIATIONS = ("two_point", "single")

Associator = Callable[[np.ndarray, np.ndarray, AssociationParams], tuple[np.ndarray, np.ndarray]]


@dataclass(frozen=True, eq=False)
class Track:
    """id: label (new one per initiation); state: filter state after the last update; score, max_score:
    track LLR score and its running maximum; confirmed; age: scans since birth (1 at birth);
    hits: scans with at least one gated measurement (birth counts); misses_in_a_row: consecutive
    scans without one; candidate: a one-measurement track candidate waiting for a second measurement
    (two-point initiation; id -1, not associated, not reported)."""

    id: int
    state: FilterState
    score: float
    max_score: float
    confirmed: bool
    age: int
    hits: int
    misses_in_a_row: int
    candidate: bool = False


@dataclass(frozen=True)
class TrackerParams:
    """Tracker parameters. Units: m, s. Defaults: highway traffic seen at 10 Hz, thesis §4, §7.2 [D].

    sigma_v [m/s^2] white-acceleration std; sigma_w [m] position noise std; pd detection probability;
    gate_alpha chi-square gate (2 dof); clutter_density lambda [m^-2]; new_target_density beta_NT [m^-2];
    v_max [m/s] initial velocity bound; alpha_fc, beta_tm SPRT error probabilities; delta_del score drop
    deleting a confirmed track (None -> |T_d|); initial_score_pd add ln P_D to the initial score;
    use_pg JPDA/GNN in the P_D P_G form; max_jpda_events, jpda_overflow: JPDA cluster cap and fallback;
    score_mode: "gate" (thesis §7.2: every measurement in the track's own gate counts) or "exclusive"
    ([D], not in the thesis: measurement i counts for track t with weight 1 - sum_{s != t} W[s, i], the
    probability that no other track claims it, which stops duplicate tracks from feeding on a target
    that another track already holds); initiation: "two_point" ([D], thesis §7.2's alternative: a
    measurement in no track's gate becomes a candidate, and a track is started only when a measurement of
    the next scan lies within v_max dt + 3 sqrt(2) sigma_w of it, with two-point differencing) or "single"
    (§7.2: a tentative track at once, velocity 0, P_v = v_max^2/3)."""

    sigma_v: float = 2.0
    sigma_w: float = 0.3
    pd: float = 0.9
    gate_alpha: float = 16.0
    clutter_density: float = 1e-2
    new_target_density: float = 1e-3
    v_max: float = 40.0
    alpha_fc: float = 1e-4
    beta_tm: float = 1e-2
    delta_del: float | None = None
    initial_score_pd: bool = False
    use_pg: bool = False
    max_jpda_events: int = 50_000
    jpda_overflow: str = "pda"
    score_mode: str = "gate"
    initiation: str = "two_point"

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if f.type == "float" and (isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v)):
                raise ValueError(f"TrackerParams.{f.name} must be a finite number, got {v!r}")
        if self.sigma_v < 0 or self.sigma_w <= 0 or self.gate_alpha <= 0 or self.v_max <= 0:
            raise ValueError("TrackerParams needs sigma_v >= 0 and sigma_w, gate_alpha, v_max > 0")
        if self.score_mode not in SCORE_MODES:
            raise ValueError(f"TrackerParams.score_mode must be one of {list(SCORE_MODES)}, got {self.score_mode!r}")
        if self.initiation not in INITIATIONS:
            raise ValueError(f"TrackerParams.initiation must be one of {list(INITIATIONS)}, got {self.initiation!r}")
        if self.jpda_overflow not in OVERFLOW_MODES:
            raise ValueError(f"TrackerParams.jpda_overflow must be one of {list(OVERFLOW_MODES)}, "
                             f"got {self.jpda_overflow!r}")
        self.association()  # the remaining fields are validated by the parameter objects they feed
        self.management()

    @property
    def pg(self) -> float:
        """Gate probability P_G = F_chi2_2(gate_alpha)."""
        return gate_probability(self.gate_alpha, MEASUREMENT_DIM)

    def association(self) -> AssociationParams:
        return AssociationParams(pd=self.pd, pg=self.pg, clutter_density=self.clutter_density, use_pg=self.use_pg,
                                 max_events=self.max_jpda_events, on_overflow=self.jpda_overflow)

    def management(self) -> ManagementParams:
        return ManagementParams(new_target_density=self.new_target_density, alpha_fc=self.alpha_fc,
                                beta_tm=self.beta_tm, delta_del=self.delta_del, initial_score_pd=self.initial_score_pd)


@dataclass(frozen=True, eq=False)
class StepInfo:
    """Per-step internals for viewers, for the T tracks that existed at the start of the step (input order),
    after prediction: ids (T,) int64, z_hat (T, m), S (T, m, m), gated (T, M) bool, W (T, M), w0 (T,)."""

    ids: np.ndarray
    z_hat: np.ndarray
    S: np.ndarray
    gated: np.ndarray
    W: np.ndarray
    w0: np.ndarray


@dataclass(frozen=True, eq=False)
class StepResult:
    """tracks: surviving input tracks (input order) then new tentative tracks (measurement order);
    next_id: first unused label; deleted: tracks deleted in this step (their final state); info: StepInfo."""

    tracks: tuple[Track, ...]
    next_id: int
    deleted: tuple[Track, ...]
    info: StepInfo


def _check_measurements(Z) -> np.ndarray:
    Z = np.asarray(Z, dtype=np.float64)
    if Z.size == 0:
        return np.zeros((0, MEASUREMENT_DIM))
    if Z.ndim != 2 or Z.shape[1] != MEASUREMENT_DIM:
        raise ValueError(f"Z must have shape (M, {MEASUREMENT_DIM}), got {Z.shape}")
    bad = np.flatnonzero(~np.isfinite(Z).all(axis=1))
    if bad.size:
        raise ValueError(f"Z has non-finite rows {bad.tolist()}")
    return Z


@dataclass(frozen=True)
class Tracker:
    """filter: a `Filter`; associate: fn(log_lik, gated, AssociationParams) -> (W, w0); params: TrackerParams.

    A filter attribute that is also a TrackerParams field (e.g. sigma_v, sigma_w) must agree with it."""

    filter: Filter
    associate: Associator
    params: TrackerParams = field(default_factory=TrackerParams)
    association_params: AssociationParams = field(init=False, repr=False)
    management_params: ManagementParams = field(init=False, repr=False)

    def __post_init__(self) -> None:
        for f in fields(self.params):
            if hasattr(self.filter, f.name) and getattr(self.filter, f.name) != getattr(self.params, f.name):
                raise ValueError(f"filter.{f.name}={getattr(self.filter, f.name)!r} disagrees with "
                                 f"params.{f.name}={getattr(self.params, f.name)!r}")
        object.__setattr__(self, "association_params", self.params.association())
        object.__setattr__(self, "management_params", self.params.management())

    def step(self, tracks: tuple[Track, ...], Z: np.ndarray, dt: float, next_id: int) -> StepResult:
        """One scan. tracks: current tracks; Z (M, 2) measurements [m]; dt [s] since the last scan;
        next_id: label for the next new track. Raises ValueError on non-finite Z or dt before any update."""
        Z = _check_measurements(Z)
        dt = float(dt)
        if not math.isfinite(dt) or dt < 0:
            raise ValueError(f"dt must be finite and >= 0, got {dt}")
        candidates = tuple(tr for tr in tracks if tr.candidate)
        tracks = tuple(tr for tr in tracks if not tr.candidate)
        p, ap, mp = self.params, self.association_params, self.management_params
        flt = self.filter
        T, M, m = len(tracks), len(Z), MEASUREMENT_DIM

        preds = [flt.predict(tr.state, dt) for tr in tracks]  # 1. predict all
        zs = [flt.predicted_measurement(s) for s in preds]
        z_hat = np.array([z for z, _ in zs], dtype=np.float64).reshape(T, m)
        S = np.array([s for _, s in zs], dtype=np.float64).reshape(T, m, m)

        nu = innovations(z_hat, Z)  # 2. gate
        d2, log_lik = mahalanobis2_and_log_gaussian(nu, S)
        gated = gate(d2, p.gate_alpha)

        W, w0 = self.associate(log_lik, gated, ap)  # 3. associate
        W, w0 = np.asarray(W, dtype=np.float64), np.asarray(w0, dtype=np.float64)
        if W.shape != (T, M) or w0.shape != (T,):
            raise ValueError(f"associator returned W {W.shape} and w0 {w0.shape}, expected ({T}, {M}) and ({T},)")

        states = []  # 4. update each track
        for t in range(T):
            idx = np.flatnonzero(W[t] > 0.0)
            states.append(flt.update(preds[t], nu[t, idx], W[t, idx], float(w0[t])))

        score = np.array([tr.score for tr in tracks], dtype=np.float64).reshape(T)  # 5. score
        if p.score_mode == "gate":
            score = score + score_increment(log_lik, gated, ap.pd, ap.pg, ap.clutter_density)
        else:  # "exclusive" [D]: L_ti weighted by rho_ti = 1 - sum_{s != t} W[s, i] (no other track claims z_i)
            rho = np.clip(1.0 - (W.sum(axis=0)[None, :] - W), 0.0, 1.0)
            with np.errstate(divide="ignore"):
                score = score + score_increment(log_lik + np.log(rho), gated & (rho > 0.0), ap.pd, ap.pg,
                                                ap.clutter_density)
        max_score = np.maximum(np.array([tr.max_score for tr in tracks], dtype=np.float64).reshape(T), score)
        confirmed, delete = decide(score, max_score, np.array([tr.confirmed for tr in tracks], dtype=bool), mp)  # 6.

        hit = gated.any(axis=1)
        survivors, deleted = [], []
        for t, tr in enumerate(tracks):
            new = replace(tr, state=states[t], score=float(score[t]), max_score=float(max_score[t]),
                          confirmed=bool(confirmed[t]), age=tr.age + 1, hits=tr.hits + int(hit[t]),
                          misses_in_a_row=0 if hit[t] else tr.misses_in_a_row + 1)
            (deleted if delete[t] else survivors).append(new)

        score0 = initial_score(mp, ap.clutter_density, ap.pd)  # 7. initiate from measurements in no gate (§7.2)
        free = np.flatnonzero(~gated.any(axis=0))
        if p.initiation == "single":
            for j in free:
                survivors.append(Track(id=int(next_id), state=flt.initiate(Z[j], p.v_max), score=score0,
                                       max_score=score0, confirmed=False, age=1, hits=1, misses_in_a_row=0))
                next_id += 1
        else:
            pairs = _pair_candidates(candidates, Z[free], dt, p) if dt > 0 else []
            used = set()
            for c, f, score in pairs:
                j = free[f]
                used.add(f)
                s0 = flt.initiate_two_point(candidates[c].state.x[:MEASUREMENT_DIM], Z[j], dt)
                survivors.append(Track(id=int(next_id), state=s0, score=score0 + score, max_score=score0 + score,
                                       confirmed=False, age=2, hits=2, misses_in_a_row=0))
                next_id += 1
            for f, j in enumerate(free):
                if f not in used:
                    survivors.append(Track(id=-1, state=flt.initiate(Z[j], p.v_max), score=score0,
                                           max_score=score0, confirmed=False, age=1, hits=1, misses_in_a_row=0,
                                           candidate=True))

        info = StepInfo(ids=np.array([tr.id for tr in tracks], dtype=np.int64).reshape(T), z_hat=z_hat, S=S,
                        gated=gated, W=W, w0=w0)
        return StepResult(tracks=tuple(survivors), next_id=int(next_id), deleted=tuple(deleted), info=info)


def _pair_candidates(candidates: tuple[Track, ...], Zf: np.ndarray, dt: float,
                     p: TrackerParams) -> list[tuple[int, int, float]]:
    """Two-point initiation [D]: one-to-one pairs (candidate, free measurement, score increment) within
    reach = v_max dt + 3 sqrt(2) sigma_w, nearest first (min total distance). The increment is the
    likelihood ratio of the second measurement, ln(P_D g / lambda), g = 1 / (pi reach^2) its density
    under a velocity uniform on the disk |v| <= v_max (§7.2-style LLR)."""
    if not candidates or len(Zf) == 0:
        return []
    C = np.array([c.state.x[:MEASUREMENT_DIM] for c in candidates], dtype=np.float64)
    D = np.linalg.norm(C[:, None, :] - Zf[None, :, :], axis=-1)
    reach = p.v_max * dt + 3.0 * math.sqrt(2.0) * p.sigma_w
    rows, cols = linear_sum_assignment(np.where(D <= reach, D, 1e12))
    inc = math.log(p.pd / (math.pi * reach * reach) / p.clutter_density)
    return [(int(r), int(c), inc) for r, c in zip(rows, cols) if D[r, c] <= reach]
