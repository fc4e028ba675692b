"""One measurement per step of unknown origin: the "mixed-measurement" sensor of paper 000 (§II, §IV).

A fixed tower sees a convoy of C cars and returns exactly one 2-D Cartesian position per step, with no
clutter and no misses. Usually it is the tracked car's position plus noise; at the "wrong" steps it is, unknown
to the sensor, a neighbouring car's (paper 000 §IV: "randomly replacing measurements ... with measurements from
the car driving close to the first"). The origin of every measurement travels beside it for scoring only.

    wrong_steps(K, fraction, rng, mode)      -> (K,) bool   which steps carry a neighbour's measurement
    mixed_measurements(positions, target, sigma, wrong, rng)
                                             -> MixedMeasurements(z (K, 2), origin (K,), per_car (K, C, 2))

Units: m. Random streams: draw the mixing mask and the noise from separate generators (e.g.
``SeedSequence(seed).spawn``) so that changing the fraction does not change the noise; the noise of every car is
drawn at every step whatever the mask says.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from roadtrack.sensors import checks

MIX_MODES = {"fraction": "exactly round(fraction K) wrong steps at distinct random positions (paper 000 §IV)",
             "probability": "each step independently wrong with probability `fraction` [D]"}


@dataclass(frozen=True, eq=False)
class MixedMeasurements:
    """z (K, 2): the one measurement of each step [m]; origin (K,) int64: the car that produced it (scoring only);
    per_car (K, C, 2): every car's noisy sample, of which z picks one per step (paper 000 §IV: "two lists")."""

    z: np.ndarray
    origin: np.ndarray
    per_car: np.ndarray

    def wrong(self, target: int) -> np.ndarray:
        """(K,) bool: the measurement did not come from car `target`."""
        return self.origin != target


def wrong_steps(K: int, fraction: float, rng: np.random.Generator, mode: str = "fraction") -> np.ndarray:
    """(K,) bool mask of the steps whose measurement comes from a neighbour.

    mode "fraction" (paper 000 §IV): N = round(fraction K) distinct steps drawn uniformly without replacement;
    mode "probability": each step independently with probability `fraction`."""
    checks.positive_int("K", K, allow_zero=True)
    checks.finite("fraction", fraction)
    if not 0.0 <= fraction <= 1.0:
        raise ValueError(f"fraction: expected a number in [0, 1], got {fraction!r}")
    checks.choice("mode", mode, MIX_MODES)
    mask = np.zeros(K, dtype=bool)
    if mode == "fraction":
        mask[rng.choice(K, size=int(round(fraction * K)), replace=False)] = True  # paper 000 §IV mixing rule
    else:
        mask[:] = rng.random(K) < fraction
    return mask


def mixed_measurements(positions: np.ndarray, target: int, sigma: float, wrong: np.ndarray,
                       rng: np.random.Generator, neighbour_rng: np.random.Generator | None = None
                       ) -> MixedMeasurements:
    """The sensor's stream for car `target` of a convoy.

    positions (K, C, 2): true positions of the C cars at the K measurement times [m], cars in convoy order (so
    the neighbours of car c are c - 1 and c + 1); target: index of the tracked car; sigma: noise std per axis
    [m] (paper 000 §IV: 0.5 m); wrong (K,) bool: steps that return a neighbour's measurement (see
    `wrong_steps`); rng: the noise generator; neighbour_rng: picks which neighbour (uniformly [D]) when the
    target has two (default: `rng`, drawn after the noise, so the noise never depends on the choice)."""
    pos = checks.float_array("positions", positions, (None, None, 2))
    K, C = pos.shape[:2]
    checks.positive("sigma", sigma)
    if isinstance(target, bool) or not isinstance(target, (int, np.integer)) or not 0 <= target < C:
        raise ValueError(f"target: expected a car index in [0, {C - 1}], got {target!r}")
    mask = np.asarray(wrong)
    if mask.dtype != np.bool_ or mask.shape != (K,):
        raise ValueError(f"wrong: expected a ({K},) bool array, got {mask.dtype} {mask.shape}")
    neighbours = [c for c in (target - 1, target + 1) if 0 <= c < C]
    if mask.any() and not neighbours:
        raise ValueError("wrong steps need a convoy of at least 2 cars")
    per_car = pos + sigma * rng.standard_normal((K, C, 2))  # paper 000 §IV: z_c(k) = p_c(k) + w_c(k), w ~ N(0, sigma^2 I)
    pick = neighbour_rng if neighbour_rng is not None else rng
    origin = np.full(K, target, dtype=np.int64)
    if neighbours:
        choice = np.asarray(neighbours, dtype=np.int64)[pick.integers(len(neighbours), size=K)]
        origin = np.where(mask, choice, origin)  # paper 000 §IV: the neighbour's sample replaces the target's
    z = per_car[np.arange(K), origin]
    return MixedMeasurements(z=z, origin=origin, per_car=per_car)
