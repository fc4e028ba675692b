"""Symmetric-measurement sensors for N = 2 and 3 point targets on a line (paper 003).

The sensor sees the positions z_i = x_i + u_i, u_i ~ N(0, sigma^2) i.i.d. (paper 003 eq. (2), the "associated"
measurement), but reports only a symmetric function of them, so which value came from which target is unknown:

    sum of powers     y = [sum z_i, sum z_i^2 (, sum z_i^3)]                     (paper 003 §II eq. (3))
    sum of products   y = [z1 + z2, z1 z2]  or  [e_1, e_2, z1 z2 z3] of three   (paper 003 §II)

Writing y = g(x) + nu, the transformed noise nu has the mean and covariance coded below in closed form for
N = 2 and 3 (paper 003 §II-III; the printed matrices are lost, so the closed forms are reconstructed from the
Gaussian moments E u^2 = sigma^2, E u^4 = 3 sigma^4, E u^6 = 15 sigma^6, odd moments 0, and checked against Monte
Carlo by `monte_carlo_moments`). This module does not import `trackers`: the filter's h(x) and R(x) live in
trackers/sme.py (a general-N derivation) and a test checks that the two agree.

Shapes: positions (..., N) -> measurements (..., N), covariances (..., N, N); units m (y_m in m^m).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

FORMS = ("powers", "products")


def associated_positions(positions: np.ndarray, sigma: float, rng: np.random.Generator) -> np.ndarray:
    """z = x + u (..., N), u ~ N(0, sigma^2) i.i.d.: the labelled linear measurement (paper 003 eq. (2))."""
    positions = np.asarray(positions, dtype=np.float64)
    return positions + sigma * rng.standard_normal(positions.shape)


def _powers(z: np.ndarray) -> np.ndarray:
    n = z.shape[-1]
    return np.stack([(z ** m).sum(axis=-1) for m in range(1, n + 1)], axis=-1)  # paper 003 eq. (3)


def _products(z: np.ndarray) -> np.ndarray:
    if z.shape[-1] == 2:
        return np.stack([z[..., 0] + z[..., 1], z[..., 0] * z[..., 1]], axis=-1)  # paper 003 §II, two particles
    z1, z2, z3 = z[..., 0], z[..., 1], z[..., 2]
    return np.stack([z1 + z2 + z3, z1 * z2 + z1 * z3 + z2 * z3, z1 * z2 * z3], axis=-1)  # paper 003 §II, three


def _mean_powers(x: np.ndarray, s2: float) -> np.ndarray:
    zero = np.zeros(x.shape[:-1])
    if x.shape[-1] == 2:
        return np.stack([zero, zero + 2 * s2], axis=-1)  # paper 003 §II: E[nu] = [0, 2 sigma^2]
    # reconstructed (paper 003 §II asserts zero mean): E[nu] = [0, 3 sigma^2, 3 sigma^2 S_1]
    return np.stack([zero, zero + 3 * s2, 3 * s2 * x.sum(axis=-1)], axis=-1)


def _cov_powers(x: np.ndarray, s2: float) -> np.ndarray:
    S = [(x ** m).sum(axis=-1) for m in range(5)]  # S_m = sum_i x_i^m (S_0 = N)
    if x.shape[-1] == 2:
        rows = [[2 * s2, 2 * s2 * S[1]],
                [2 * s2 * S[1], 4 * s2 * S[2] + 4 * s2 ** 2]]  # reconstructed: paper 003 §III R_k, powers, N = 2
        return _matrix(rows)
    r13 = 3 * s2 * S[2] + 9 * s2 ** 2
    r23 = 6 * s2 * S[3] + 12 * s2 ** 2 * S[1]
    rows = [[3 * s2, 2 * s2 * S[1], r13],
            [2 * s2 * S[1], 4 * s2 * S[2] + 6 * s2 ** 2, r23],
            [r13, r23, 9 * s2 * S[4] + 36 * s2 ** 2 * S[2] + 45 * s2 ** 3]]  # reconstructed: §III R_k, powers, N = 3
    return _matrix(rows)


def _cov_products(x: np.ndarray, s2: float) -> np.ndarray:
    if x.shape[-1] == 2:
        x1, x2 = x[..., 0], x[..., 1]
        rows = [[2 * s2, s2 * (x1 + x2)],
                [s2 * (x1 + x2), s2 * (x1 ** 2 + x2 ** 2) + s2 ** 2]]  # reconstructed: §III R_k, products, N = 2
        return _matrix(rows)
    e1 = x.sum(axis=-1)
    e2 = x[..., 0] * x[..., 1] + x[..., 0] * x[..., 2] + x[..., 1] * x[..., 2]
    p = e1[..., None] - x  # p_i = sum_{j != i} x_j
    q = _others_product(x)  # q_i = prod_{j != i} x_j
    r23 = s2 * (p * q).sum(axis=-1) + s2 ** 2 * e1
    rows = [[3 * s2, 2 * s2 * e1, s2 * e2],
            [2 * s2 * e1, s2 * (p ** 2).sum(axis=-1) + 3 * s2 ** 2, r23],
            [s2 * e2, r23, s2 * (q ** 2).sum(axis=-1) + s2 ** 2 * (x ** 2).sum(axis=-1) + s2 ** 3]]  # reconstructed
    return _matrix(rows)


def _others_product(x: np.ndarray) -> np.ndarray:
    """prod_{j != i} x_j (..., 3) by explicit pairs."""
    return np.stack([x[..., 1] * x[..., 2], x[..., 0] * x[..., 2], x[..., 0] * x[..., 1]], axis=-1)


def _matrix(rows: list[list[np.ndarray]]) -> np.ndarray:
    """(..., N, N) from N rows of N entries (arrays of the batch shape, or scalars)."""
    flat = np.broadcast_arrays(*[np.asarray(v, dtype=np.float64) for r in rows for v in r])
    n = len(rows)
    return np.stack(flat, axis=-1).reshape(flat[0].shape + (n, n))


@dataclass(frozen=True)
class SymmetricSensor:
    """A sensor reporting a symmetric function of N = 2 or 3 positions. form: "powers" or "products";
    sigma [m]: std of the raw position noise (paper 003 §IV: sigma^2 = 25, sigma = 5)."""

    form: str
    n_targets: int
    sigma: float = 5.0

    def __post_init__(self) -> None:
        if self.form not in FORMS:
            raise ValueError(f"SymmetricSensor.form must be one of {', '.join(FORMS)}, got {self.form!r}")
        if self.n_targets not in (2, 3) or isinstance(self.n_targets, bool):
            raise ValueError(f"SymmetricSensor.n_targets must be 2 or 3, got {self.n_targets!r}")
        if not (isinstance(self.sigma, (int, float)) and math.isfinite(self.sigma) and self.sigma > 0):
            raise ValueError(f"SymmetricSensor.sigma must be a finite number > 0, got {self.sigma!r}")

    def _positions(self, x: np.ndarray) -> np.ndarray:
        x = np.asarray(x, dtype=np.float64)
        if x.shape[-1:] != (self.n_targets,):
            raise ValueError(f"positions must have shape (..., {self.n_targets}), got {x.shape}")
        return x

    def transform(self, z: np.ndarray) -> np.ndarray:
        """y (..., N): the symmetric function of positions z (..., N) (noise-free when z is the truth)."""
        z = self._positions(z)
        return _powers(z) if self.form == "powers" else _products(z)

    def measure(self, positions: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """(y, z): the symmetric measurement y (..., N) and the labelled noisy positions z it was made from
        (z is for the associated-KF baseline and for scoring; a tracker on this sensor sees only y)."""
        z = associated_positions(self._positions(positions), self.sigma, rng)
        return self.transform(z), z

    def noise_mean(self, x: np.ndarray) -> np.ndarray:
        """E[nu | x] (..., N), nu = y - g(x); zero for the sum of products."""
        x, s2 = self._positions(x), self.sigma ** 2
        return _mean_powers(x, s2) if self.form == "powers" else np.zeros_like(x)

    def noise_covariance(self, x: np.ndarray) -> np.ndarray:
        """R(x) = Cov(nu | x) (..., N, N) in closed form (paper 003 §III)."""
        x, s2 = self._positions(x), self.sigma ** 2
        return _cov_powers(x, s2) if self.form == "powers" else _cov_products(x, s2)


@dataclass(frozen=True)
class NoiseMoments:
    """Monte Carlo moments of nu at one x: mean (N,), cov (N, N), and their standard errors mean_se (N,),
    cov_se (N, N) (from the sample spread of nu_a and of the products nu_a nu_b); n samples; raw_var (N,): the
    sample variance of each target's raw noise u_i over sigma^2 (1 +- sqrt(2 / n) by chance), which tells an
    error of the draws from an error of the formulas."""

    mean: np.ndarray
    cov: np.ndarray
    mean_se: np.ndarray
    cov_se: np.ndarray
    n: int
    raw_var: np.ndarray


def monte_carlo_moments(sensor: SymmetricSensor, x: np.ndarray, n_samples: int, rng: np.random.Generator,
                        chunk: int = 250_000) -> NoiseMoments:
    """Sample nu = transform(x + u) - transform(x) n_samples times at positions x (N,) (paper 003 §III: the
    expressions "are verified with ... Monte Carlo"). Sums are shifted by the first chunk's mean for accuracy."""
    x = sensor._positions(x).reshape(-1)
    g = sensor.transform(x)
    shift = None
    s1 = np.zeros(x.size)
    s2 = np.zeros((x.size, x.size))
    s4 = np.zeros((x.size, x.size))
    su2 = np.zeros(x.size)
    done = 0
    while done < n_samples:
        k = min(chunk, n_samples - done)
        z = associated_positions(np.broadcast_to(x, (k, x.size)), sensor.sigma, rng)
        su2 += ((z - x) ** 2).sum(axis=0)
        nu = sensor.transform(z) - g
        shift = nu.mean(axis=0) if shift is None else shift
        d = nu - shift
        outer = d[:, :, None] * d[:, None, :]
        s1 += d.sum(axis=0)
        s2 += outer.sum(axis=0)
        s4 += (outer ** 2).sum(axis=0)
        done += k
    m1 = s1 / done
    cov = s2 / done - np.outer(m1, m1)
    cov_se = np.sqrt(np.maximum(s4 / done - (s2 / done) ** 2, 0.0) / done)
    return NoiseMoments(mean=shift + m1, cov=cov, mean_se=np.sqrt(np.diagonal(cov) / done), cov_se=cov_se, n=done,
                        raw_var=su2 / done / sensor.sigma ** 2)
