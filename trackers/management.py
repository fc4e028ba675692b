"""Track management: confirmation and deletion by track score (SPRT) or m-of-n, coasting, duplicate pruning
(thesis §1.3.4, §7; §7.2 of our reading is the implemented score).

Score L of a track = log likelihood ratio 'real target' vs 'clutter', updated additively per scan (1.35).
    new tentative track:  L_1 = ln(beta_NT / lambda)  (+ ln P_D if `initial_score_pd`)
    per scan:             dL  = ln(1 - P_D P_G + sum_{i gated} P_D N(nu_i; 0, S) / lambda)
    confirm tentative:    L >= T_c = ln((1 - beta_TM) / alpha_FC)
    delete tentative:     L <= T_d = ln(beta_TM / (1 - alpha_FC))
    delete confirmed:     max_score - L >= delta_del; by default (coast_scans + 1/2) |ln(1 - P_D P_G)|,
                          so a confirmed track coasts through `coast_scans` missed scans in a row.
    tentative grace [D]:  a tentative track is judged against T_d + (tentative_misses - 1) ln(1 - P_D P_G) (nominal
                          P_D), so a two-point initiation survives one missed scan. A missed scan is priced with
                          the caller's P_D as a confirmed track's is (`tentative_pd`): a miss in a sensor shadow
                          (P_D ~0) costs nothing, and the life bounds below end a tentative track the sensor cannot
                          see; a detected scan with at least the nominal P_D (the caller's may be wrong: a car
                          detected 4 scans running under an occlusion P_D of 0.02-0.1 on highway_benchmark).
m-of-n (thesis §1.3.4, the alternative): confirm with >= m detections in the last n scans; delete a
tentative track that can no longer reach m; delete a confirmed one after coast_scans + 1 misses in a row.
Life bounds [D] (whatever the manager and the P_D; as Stone Soup's CovarianceBasedDeleter and
UpdateTimeDeleter): a track whose position standard deviation (square root of the largest eigenvalue of its
position covariance after the scan) exceeds `max_position_std_m`, or that has gone `max_unseen_s` without a
gated measurement, is deleted: a track the sensor cannot see (P_D ~ 0, so no score loss) coasts until what is
known about it is no longer worth a track.
Life with a road map [D] (when the caller gives the road, trackers.road): a confirmed track the sensor cannot
see (occlusion-aware P_D ~ 0, so no score loss) stays alive while it is still credible for re-acquisition:
its cross-lane std at most `max_position_std_m` (lane keeping holds it within a lane), its gate at most
`max_gate_m2` (checked on the predicted gate, before association: a track leaves before its gate passes the
bound; a hidden car's along-lane std grows as sigma_v t^(3/2): with sigma_v = 4 m/s^2 at 10 Hz and a 4 m
lane, the 1000 m^2 gate at alpha = 16 is reached after about 7.5 s hidden) and, while it has no gated
measurement, no other confirmed track's predicted position inside its 1-sigma region (`credible_d2`: it could
not tell its car from that one). `max_unseen_s` is then not applied: the gate bound is the time bound, set by
the road (lane width) and the track's own uncertainty. A track the sensor should see but does not detect
loses score and is deleted by the score rule as without a road.
Initiation [D]: a measurement starts a track unless it lies in the gate of a track that is well localised
(gate standard deviation, sqrt of the largest eigenvalue of S, at most `claim_std_m`) or young and just detected
(at most `claim_age_scans` old, detected in the last scan) and within `claim_d2` of its prediction (the 99 % point
of chi^2_2: where the track's own car's measurement falls; a young track's gate, 4.9 m wide, reaches the car in the
next lane), or lies within `claim_radius_m` of the track's predicted position: the huge gate of a coasting track,
or of an old one held wide by the spread of several measurements it keeps gating, blocks no new track beyond that
radius.
Duplicates [D]: two confirmed tracks sharing a gated measurement whose predicted positions lie within
`merge_d2` of each other, in the squared Mahalanobis distance under the smaller of their two S (the better
localised one's), are a duplicate pair; the worse of the two (more scans since its last detection, then the
larger |S|, then the younger label) is deleted after `merge_scans` such scans in a row.
KS deletion (paper 002, optional): every track carries a regime from the KS track regime detector
(trackers.trackloss.regime); `deletion = "ks"` deletes a confirmed track whose regime is track-lost instead of
by the manager's rule, "manager+ks" by either; the default "manager" leaves deletion as above.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from roadtrack.trackers.association.pda import pda_log_denominator
from roadtrack.trackers.params import NON_NEGATIVE, OPEN_PROBABILITY, POSITIVE, ParamError, load, param
from roadtrack.trackers.trackloss.regime import RegimeConfig


@functools.lru_cache(maxsize=64)
def _regime_config(n: int, alphas: tuple[float, ...], adaptive: bool, n_min: int, n_max: int) -> RegimeConfig:
    return RegimeConfig(n=n, alphas=alphas, adaptive=adaptive, n_min=n_min, n_max=n_max)

INITIATIONS = ("two_point", "single")
DELETIONS = ("manager", "ks", "manager+ks")
SCORE_MODES = ("gate", "exclusive")
TENTATIVE_PDS = ("misses", "nominal")


WINDOW_MAX = 3000
"""Largest history, m-of-n or KS window [scans] (5 min at 10 Hz): every track keeps that many scan records
and the KS test sorts a window per track and scan."""


@dataclass(frozen=True)
class ManagementParams:
    """Initiation, confirmation, deletion and duplicate pruning. Defaults: highway traffic at 10 Hz, §7.2 [D]."""

    initiation: str = param("two_point", "two_point: a measurement in no gate waits for a partner within "
                            "v_max dt + 3 sqrt(2) sigma_w in the next scan (two-point differencing, §7.2); "
                            "single: a tentative track at once, velocity 0", choices=INITIATIONS)
    v_max: float = param(40.0, "largest target speed [m/s] (initial velocity spread, two-point reach)",
                         check=POSITIVE)
    new_target_density: float = param(1e-3, "new-target density beta_NT [1/m^2] (initial score, §7.2)",
                                      check=POSITIVE)
    alpha_fc: float = param(1e-4, "SPRT false-confirmation probability", check=OPEN_PROBABILITY)
    beta_tm: float = param(1e-2, "SPRT true-track-deletion probability", check=OPEN_PROBABILITY)
    delta_del: float | None = param(None, "score drop [nats] that deletes a confirmed track (default: "
                                    "coast_scans + 1/2 missed scans' worth)", check=POSITIVE)
    coast_scans: int = param(5, "missed scans in a row a confirmed track survives (predicting) before deletion",
                             check=NON_NEGATIVE)
    initial_score_pd: bool = param(False, "add ln P_D to the initial score")
    score_mode: str = param("gate", "gate: every measurement in the track's gate counts (§7.2); exclusive: "
                            "weighted by the probability that no other track claims it [D]", choices=SCORE_MODES)
    confirm_m: int = param(3, "m_of_n: detections needed ...", check=POSITIVE, bounds=(1, WINDOW_MAX))
    confirm_n: int = param(5, "m_of_n: ... in the last n scans", check=POSITIVE, bounds=(1, WINDOW_MAX))
    merge_d2: float = param(4.0, "duplicate test: squared Mahalanobis distance between two confirmed tracks' "
                            "predicted positions under the smaller of their S (0 disables pruning)",
                            check=NON_NEGATIVE)
    merge_scans: int = param(5, "duplicate test: scans in a row before the worse track of a pair (less recently "
                             "detected, then less well localised, then younger) is deleted", check=POSITIVE)
    max_position_std_m: float | None = param(7.5, "delete a track whose position std (sqrt of the largest "
                                             "eigenvalue of its position covariance) exceeds this [m]; default: "
                                             "two 3.75 m lanes, beyond which it cannot tell three lanes apart "
                                             "[D]; None: no bound", check=POSITIVE)
    max_unseen_s: float | None = param(5.0, "delete a track without a gated measurement for longer than this [s], "
                                       "whatever its P_D; default: a car passing a 15 m truck at 3 m/s relative "
                                       "speed [D]; None: no bound", check=POSITIVE)
    claim_std_m: float | None = param(2.0, "a measurement in the gate of a track whose gate std (sqrt of the "
                                      "largest eigenvalue of S) is at most this [m] starts no new track; larger "
                                      "gates do not block initiation; default: about half a lane [D]; None: every "
                                      "gate blocks (the thesis's rule)", check=POSITIVE)
    claim_radius_m: float | None = param(3.0, "a gated measurement this close [m] to the predicted position of a "
                                         "track whose gate is wider than claim_std_m is still claimed by it (the "
                                         "car it follows); farther ones, e.g. of a car a wide track trails by "
                                         "5-8 m, may start tracks [D]; None: such tracks claim nothing",
                                         check=POSITIVE)
    claim_d2: float | None = param(9.21, "a track claims a gated measurement (by claim_std_m or claim_age_scans) only "
                                   "within this squared Mahalanobis distance of its prediction (default: the 99 % point of "
                                   "chi^2_2, where its own car's measurement falls), or within claim_radius_m: a young "
                                   "track's gate (std 1.2 m, radius 4.9 m at alpha = 16) reaches the car in the next lane, "
                                   "4 m away [D]; None: its whole gate", check=POSITIVE)
    claim_age_scans: int = param(3, "a track at most this many scans old that was detected in the last scan claims "
                                 "its gated measurements whatever its gate std (a young track's S is wide) [D]",
                                 check=POSITIVE, bounds=(1, WINDOW_MAX))
    road_curvature: bool = param(True, "with a road from the caller: the lane's centripetal acceleration "
                                 "v_t^2 kappa enters each prediction as a known input (trackers.road) [D]")
    road_curvature_spread: bool = param(True, "the curvature input is uncertain by its own size: its shift B u "
                                        "adds (B u)(B u)^T to the predicted covariance, so a car that leaves the "
                                        "lane's bend (a roundabout's exit) is not held on it; an IMM's linear modes take the input "
                                        "exact, its turn-rate mode being the alternative (trackers.road) [D]")
    road_lane_keeping: bool = param(True, "with a road from the caller: a confirmed track with no gated measurement "
                                    "is updated with the pseudo-measurement 'in its nearest lane' (cross-lane offset "
                                    "0, variance w^2/3 for half width w; trackers.road) [D]")
    lane_keeping_max_cross_mps: float = param(0.5, "lane keeping only for a track whose velocity across its lane "
                                              "is at most this [m/s]: a car changing lanes (1.5-5 m/s across) "
                                              "coasts on to its new lane instead of being held in the old one [D]",
                                              check=POSITIVE)
    road_life: bool = param(True, "with a road from the caller: a track lives while credible for re-acquisition "
                            "(cross-lane std, gate area, neighbours; module docstring) instead of the max_unseen_s "
                            "clock and the isotropic max_position_std_m [D]")
    max_gate_m2: float | None = param(1000.0, "with a road from the caller: delete a track whose predicted gate "
                                      "(at alpha = 16, the default gate) exceeds this area [m^2]; it replaces max_unseen_s "
                                      "and bounds a hidden track's life (module docstring) [D]; None: no bound",
                                      check=POSITIVE)
    credible_d2: float | None = param(1.0, "with a road from the caller: delete a track without a gated measurement "
                                      "whose 1-sigma region (squared Mahalanobis distance under its own S at most "
                                      "this) holds another confirmed track's predicted position: it can no longer "
                                      "tell its car from that one [D]; None: no such test", check=POSITIVE)
    tentative_misses: int = param(2, "missed scans in a row a tentative track may take below the SPRT deletion "
                                  "threshold: it is judged against T_d + (tentative_misses - 1) ln(1 - P_D P_G) "
                                  "(1: the plain SPRT) [D]", check=POSITIVE, bounds=(1, WINDOW_MAX))
    tentative_pd: str = param("misses", "P_D in a tentative track's score on a scan without a gated measurement: "
                              "misses (the caller's per-track P_D, as in a confirmed track's: a miss in a sensor shadow "
                              "costs nothing, and the life bounds end a tentative track the sensor cannot see) or "
                              "nominal (at least the associator's pd: each such miss costs |ln(1 - P_D P_G)|, as before "
                              "issue 29); a scan with one uses at least the associator's pd either way [D]",
                              choices=TENTATIVE_PDS)
    history_length: int = param(32, "scans of innovations, S, gated counts and gate volumes kept per track "
                                "(at least the KS regime window)", check=POSITIVE, bounds=(1, WINDOW_MAX))
    deletion: str = param("manager", "manager: the manager's own deletion (score drop or m-of-n misses); ks: a "
                          "confirmed track is deleted when its KS regime is track-lost (paper 002), tentative ones "
                          "by the manager; manager+ks: either", choices=DELETIONS)
    regime_n: int = param(30, "KS regime detector window n [scans] (paper 002: 50 at its 1-D example; 30 = 3 s "
                          "at 10 Hz [D]); the start value when adaptive", check=POSITIVE,
                          bounds=(1, WINDOW_MAX))
    regime_alpha: float = param(0.05, "KS regime detector significance alpha (CI = 1 - alpha; paper 002: 0.05)",
                                check=OPEN_PROBABILITY)
    regime_adaptive: bool = param(False, "adapt the window n (paper 002 §V-F): grow it while both regimes are "
                                  "accepted, shrink it while neither is, raise the CI to 99 % when that fails")
    regime_n_min: int = param(5, "adaptive KS window: smallest n", check=POSITIVE, bounds=(1, WINDOW_MAX))
    regime_n_max: int = param(100, "adaptive KS window: largest n (scans of history kept per track)",
                              check=POSITIVE, bounds=(1, WINDOW_MAX))
    regime_clutter_density: float | None = param(None, "clutter density lambda for the KS regime [1/m^2] "
                                                 "(default: the associator's; paper 002 §VI-B: err high)",
                                                 check=POSITIVE)

    def __post_init__(self) -> None:
        if self.alpha_fc + self.beta_tm >= 1:
            raise ParamError("beta_tm", f"alpha_fc + beta_tm must be < 1, got {self.alpha_fc} + {self.beta_tm}")
        if self.confirm_m > self.confirm_n:
            raise ParamError("confirm_m", f"must be <= confirm_n = {self.confirm_n}, got {self.confirm_m}")
        if self.regime_adaptive and not self.regime_n_min <= self.regime_n <= self.regime_n_max:
            raise ParamError("regime_n", f"must lie in [regime_n_min, regime_n_max] = [{self.regime_n_min}, "
                             f"{self.regime_n_max}] when adaptive, got {self.regime_n}")

    @property
    def regime_config(self) -> RegimeConfig:
        """The KS regime detector's configuration (CI ladder: regime_alpha, then 0.01 if smaller)."""
        alphas = (self.regime_alpha,) + ((0.01,) if self.regime_alpha > 0.01 else ())
        return _regime_config(self.regime_n, alphas, self.regime_adaptive, min(self.regime_n_min, self.regime_n),
                              max(self.regime_n_max, self.regime_n))

    @property
    def confirm_threshold(self) -> float:
        """T_c = ln((1 - beta_TM) / alpha_FC) (about 9.2 by default)."""
        return math.log((1.0 - self.beta_tm) / self.alpha_fc)  # §7.2 SPRT confirmation threshold

    @property
    def delete_threshold(self) -> float:
        """T_d = ln(beta_TM / (1 - alpha_FC)) (about -4.6 by default)."""
        return math.log(self.beta_tm / (1.0 - self.alpha_fc))  # §7.2 SPRT deletion threshold

    def deletion_drop(self, pd: float = 0.9, pg: float = 0.99966) -> float:
        """Score drop from the running maximum that deletes a confirmed track."""
        if self.delta_del is not None:
            return float(self.delta_del)
        return (self.coast_scans + 0.5) * -math.log1p(-pd * pg) if pd * pg < 1 else math.inf


def initial_score(mp: ManagementParams, clutter_density: float, pd: float) -> float:
    """L_1 = ln(beta_NT / lambda) (+ ln P_D)."""
    score = math.log(mp.new_target_density / clutter_density)  # §7.2 initial score
    return score + math.log(pd) if mp.initial_score_pd else score


def score_increment(log_lik: np.ndarray, gated: np.ndarray, pd: np.ndarray | float, pg: float,
                    clutter_density: float) -> np.ndarray:
    """dL (T,) = ln(1 - P_D P_G + sum_{gated i} P_D N_i / lambda) from log N (T, M) and gate flags (T, M)."""
    return pda_log_denominator(log_lik, gated, pd, pg, clutter_density)  # §7.2 / (1.35) score increment


def score_decide(score: np.ndarray, max_score: np.ndarray, confirmed: np.ndarray, mp: ManagementParams,
                 drop: float | np.ndarray, miss_loss: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """SPRT confirmation and deletion: (confirmed_after (T,) bool, delete (T,) bool). Confirmation is checked
    first, so a track confirmed in this scan is judged by the confirmed-track rule; drop: deletion drop (T,);
    miss_loss = -ln(1 - P_D P_G) >= 0, the score one missed scan costs (the tentative grace)."""
    confirmed = np.asarray(confirmed, dtype=bool) | (score >= mp.confirm_threshold)  # §7.2 confirm
    tentative_floor = mp.delete_threshold - (mp.tentative_misses - 1) * miss_loss  # [D] tentative grace
    delete = np.where(confirmed, max_score - score >= drop,  # §7.2 delete confirmed on score drop
                      score <= tentative_floor)  # §7.2 delete tentative
    return confirmed, delete


def miss_loss(pd: float, pg: float) -> float:
    """-ln(1 - P_D P_G): the score a missed scan costs (inf when P_D P_G = 1)."""
    return -math.log1p(-pd * pg) if pd * pg < 1 else math.inf


def m_of_n_decide(detected: np.ndarray, misses_in_a_row: np.ndarray, confirmed: np.ndarray,
                  mp: ManagementParams, known: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """m-of-n (thesis §1.3.4): detected (T, n) flags of the last n scans (newest last); known (T, n) marks the
    scans of the track's life (scans before its birth are neither hits nor misses; default: all known)."""
    known = np.ones_like(detected, dtype=bool) if known is None else known
    hits = (detected & known).sum(axis=1)
    window_misses = (~detected & known).sum(axis=1)
    confirmed = np.asarray(confirmed, dtype=bool) | (hits >= mp.confirm_m)  # §1.3.4: m of the last n
    delete = np.where(confirmed, misses_in_a_row > mp.coast_scans, window_misses > mp.confirm_n - mp.confirm_m)
    return confirmed, delete


def duplicate_counts(z_hat: np.ndarray, S: np.ndarray, gated: np.ndarray, confirmed: np.ndarray,
                     ids: np.ndarray, counts: np.ndarray, merge_d2: float, misses: np.ndarray,
                     logdet: np.ndarray | None = None) -> np.ndarray:
    """Scans in a row (T,) each confirmed track has been the worse of a duplicate pair (module docstring): two
    confirmed tracks sharing a gated measurement, predicted measurements z_hat (T, m) within `merge_d2` under the
    smaller (by determinant) of their S (T, m, m). The worse one has more misses (T,) in a row, then the larger
    |S|, then the larger (younger) id. logdet (T,): ln|S| when the caller has it."""
    out = np.zeros(len(ids), dtype=np.int64)
    conf = np.flatnonzero(confirmed)
    if merge_d2 <= 0 or conf.size < 2:
        return out
    g = gated[conf]
    share = (gf := g.astype(np.float64)) @ gf.T > 0.0  # (C, C) share a gated measurement (exact counts, by BLAS)
    cand = np.argwhere(np.triu(share, k=1))
    if cand.size == 0:
        return out
    a, b = conf[cand[:, 0]], conf[cand[:, 1]]
    logdet = np.linalg.slogdet(S)[1] if logdet is None else logdet
    tight = np.where(logdet[a] <= logdet[b], a, b)  # the better localised of each pair
    d = z_hat[a] - z_hat[b]
    d2 = np.einsum("ki,ki->k", d, np.linalg.solve(S[tight], d[..., None])[..., 0])
    rank = np.stack([misses, logdet, ids.astype(np.float64)], axis=1)  # larger is worse, lexicographically
    ra, rb = rank[a], rank[b]  # (K, 3): tuple(ra[k]) > tuple(rb[k]), the first unequal entry deciding (NaN: unequal)
    gt, eq = ra > rb, ra == rb
    a_worse = gt[:, 0] | (eq[:, 0] & (gt[:, 1] | (eq[:, 1] & gt[:, 2])))
    worse = np.where(a_worse, a, b)
    on = np.unique(worse[d2 <= merge_d2])
    out[on] = counts[on] + 1
    return out


def position_std(P_pos: np.ndarray) -> np.ndarray:
    """sqrt of the largest eigenvalue (T,) of position covariances P_pos (T, d, d) [m]."""
    if len(P_pos) == 0:
        return np.zeros(0)
    return np.sqrt(np.maximum(np.linalg.eigvalsh(P_pos)[:, -1], 0.0))


MANAGERS = ("score", "m_of_n")


def build_management(kind: str, data: dict, path: str = "management") -> ManagementParams:
    if kind not in MANAGERS:
        raise ParamError(f"{path}.kind", f"unknown manager {kind!r}; allowed: {', '.join(MANAGERS)}")
    return load(ManagementParams, data, path)
