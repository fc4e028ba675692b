"""Track management by log-likelihood-ratio score (thesis §7; §7.2 is the implemented definition).

Score L of a track = log likelihood ratio 'real target' vs 'clutter', updated additively per scan (1.35).
    new tentative track:  L_1 = ln(beta_NT / lambda)  (+ ln P_D if `initial_score_pd`)
    per scan:             dL  = ln(1 - P_D P_G + sum_{i gated} P_D N(nu_i; 0, S) / lambda)
    confirm tentative:    L >= T_c = ln((1 - beta_TM) / alpha_FC)
    delete tentative:     L <= T_d = ln(beta_TM / (1 - alpha_FC))
    delete confirmed:     max_score - L >= delta_del (default |T_d|)
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from trackers.association.pda import pda_log_denominator


@dataclass(frozen=True)
class ManagementParams:
    """new_target_density beta_NT [m^-2]; alpha_fc false-confirmation and beta_tm true-track-deletion
    probabilities of the SPRT; delta_del: score drop that deletes a confirmed track (None -> |T_d|);
    initial_score_pd: add ln P_D to the initial score. Defaults: thesis §7.2 [D]."""

    new_target_density: float = 1e-3
    alpha_fc: float = 1e-4
    beta_tm: float = 1e-2
    delta_del: float | None = None
    initial_score_pd: bool = False

    def __post_init__(self) -> None:
        for name in ("new_target_density", "alpha_fc", "beta_tm"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ValueError(f"ManagementParams.{name} must be a finite number, got {v!r}")
        if self.new_target_density <= 0:
            raise ValueError(f"ManagementParams.new_target_density must be > 0, got {self.new_target_density}")
        if not (0 < self.alpha_fc < 1 and 0 < self.beta_tm < 1 and self.alpha_fc + self.beta_tm < 1):
            raise ValueError(f"ManagementParams needs 0 < alpha_fc, beta_tm and alpha_fc + beta_tm < 1, "
                             f"got {self.alpha_fc}, {self.beta_tm}")
        d = self.delta_del
        if d is not None and (isinstance(d, bool) or not isinstance(d, (int, float)) or not d > 0):
            raise ValueError(f"ManagementParams.delta_del must be None or a number > 0, got {self.delta_del!r}")
        if not isinstance(self.initial_score_pd, bool):
            raise ValueError(f"ManagementParams.initial_score_pd must be a bool, got {self.initial_score_pd!r}")

    @property
    def confirm_threshold(self) -> float:
        """T_c = ln((1 - beta_TM) / alpha_FC) (about 9.2 by default)."""
        return math.log((1.0 - self.beta_tm) / self.alpha_fc)  # §7.2 SPRT confirmation threshold

    @property
    def delete_threshold(self) -> float:
        """T_d = ln(beta_TM / (1 - alpha_FC)) (about -4.6 by default)."""
        return math.log(self.beta_tm / (1.0 - self.alpha_fc))  # §7.2 SPRT deletion threshold

    @property
    def deletion_drop(self) -> float:
        """Score drop from the running maximum that deletes a confirmed track: delta_del or |T_d|."""
        return abs(self.delete_threshold) if self.delta_del is None else float(self.delta_del)


def initial_score(mp: ManagementParams, clutter_density: float, pd: float) -> float:
    """L_1 = ln(beta_NT / lambda) (+ ln P_D)."""
    score = math.log(mp.new_target_density / clutter_density)  # §7.2 initial score
    return score + math.log(pd) if mp.initial_score_pd else score


def score_increment(log_lik: np.ndarray, gated: np.ndarray, pd: float, pg: float,
                    clutter_density: float) -> np.ndarray:
    """dL (T,) = ln(1 - P_D P_G + sum_{gated i} P_D N_i / lambda) from log N (T, M) and gate flags (T, M)."""
    return pda_log_denominator(log_lik, gated, pd, pg, clutter_density)  # §7.2 / (1.35) score increment


def decide(score: np.ndarray, max_score: np.ndarray, confirmed: np.ndarray,
           mp: ManagementParams) -> tuple[np.ndarray, np.ndarray]:
    """Confirmation and deletion: (confirmed_after (T,) bool, delete (T,) bool). Confirmation is checked
    first, so a track confirmed in this scan is judged by the confirmed-track rule."""
    score, max_score = np.asarray(score, dtype=np.float64), np.asarray(max_score, dtype=np.float64)
    confirmed = np.asarray(confirmed, dtype=bool) | (score >= mp.confirm_threshold)  # §7.2 confirm
    delete = np.where(confirmed, max_score - score >= mp.deletion_drop,  # §7.2 delete confirmed on score drop
                      score <= mp.delete_threshold)  # §7.2 delete tentative
    return confirmed, delete
