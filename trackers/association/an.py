"""All-neighbours weights linear in distance, seed 001 §4 (22)-(23), reconstructed.

Each track on its own (no joint events, seed 001 §3): the N_i measurements in track i's gate share a unit
weight, linearly decreasing in their distance D_ij to the predicted measurement:

    P_i0 = 1                                          N_i = 0 (no valid observation: coast)
    P_i1 = 1                                          N_i = 1
    P_ij = (1 - D_ij / sum_l D_il) / (N_i - 1)        N_i >= 2, 1 <= j <= N_i              (22)

and no "none is correct" weight when N_i >= 1 (P_i0 = 0). So sum_j P_ij = 1; for N_i = 2 it is inverse-
distance weighting, P_i1 = D_i2 / (D_i1 + D_i2); and P_ij <= 1 / (N_i - 1) even at zero distance.

Reconstruction [R]: (22)-(23) are lost in the extracted text except the
fragments "j=0 (no valid observation)", "N", "1 - D_ij / sum D", "N-1", "1 <= j"; the N_i = 0 and N_i = 1
cases are not printed and are filled in as above. Open choices, kept as parameters:
* D_ij (23) is "the distance between the j-th observation and track i": default Euclidean
  ||z_j - z_hat_i|| [D]; alternatives Mahalanobis sqrt(nu^T S^-1 nu) and its square. The ordering is
  the same when S is a multiple of I, the weights are not.
* N is the number of observations in track i's gate [D] (the paper's §2 writes N(k) for the scan; with
  the scan count the weights of ungated observations would not be 0, so that reading is not offered).
* If every gated distance is 0 (N_i >= 2), (22) is 0/0; its limit over equal distances, 1 / N_i each, is
  used [D].
The paper's covariance (25) has no spread-of-innovations term; here the weights go to the filter in PDA
form, which adds it (the two agree when P_i0 = 0 and the spread is 0).
"""

from __future__ import annotations

import numpy as np

DISTANCES = ("euclidean", "mahalanobis", "mahalanobis2")


def an_distances(nu: np.ndarray, d2: np.ndarray, kind: str) -> np.ndarray:
    """D_ij (23) (T, M) from innovations nu (T, M, m) and squared Mahalanobis distances d2 (T, M)."""
    if kind == "euclidean":
        return np.sqrt(np.einsum("tjm,tjm->tj", nu, nu))  # seed 001 (23) [D]: ||z_j - H x_i(k|k-1)||
    if kind == "mahalanobis":
        return np.sqrt(d2)
    if kind == "mahalanobis2":
        return np.asarray(d2, dtype=np.float64)
    raise ValueError(f"AN distance must be one of {list(DISTANCES)}, got {kind!r}")


def all_neighbours(D: np.ndarray, gated: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Seed 001 (22) weights: D (T, M) distances >= 0 (read where gated), gated (T, M) bool ->
    (W (T, M), w0 (T,)). See module docstring."""
    D = np.asarray(D, dtype=np.float64)
    if D.shape != gated.shape or D.ndim != 2:
        raise ValueError(f"all_neighbours needs D and gated of the same (T, M) shape, got {D.shape}, {gated.shape}")
    Dg = np.where(gated, D, 0.0)
    if not (np.isfinite(Dg).all() and (Dg >= 0).all()):
        raise ValueError("AN distances must be finite and >= 0 at gated pairs")
    n = gated.sum(axis=1)
    total = Dg.sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        lin = (1.0 - Dg / total[:, None]) / (n - 1)[:, None]  # seed 001 (22), N_i >= 2
    W = np.where((n >= 2)[:, None] & (total > 0)[:, None], lin, 0.0)
    W = np.where(((n >= 2) & (total == 0))[:, None], 1.0 / np.maximum(n, 1)[:, None], W)  # 0/0: equal weights [D]
    W = np.where((n == 1)[:, None], 1.0, W)  # (22) a single valid observation takes all the weight [R]
    W = np.where(gated, W, 0.0)
    return W, (n == 0).astype(np.float64)  # (22) j = 0: no valid observation, coast [R]
