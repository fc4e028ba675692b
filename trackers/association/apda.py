"""Augmented PDA (APDA): association probabilities with the SVSF chattering magnitude, thesis ch. 5
§5.5, (5.37)-(5.63).

Per track, with innovations e^i = z^i - z_hat (5.38), S its covariance, psi (m,) the boundary-layer half
widths in measurement space (the filter's layer; `psi_max` where the filter has none):

    C^i = max(0, |e^i| - psi)                                       element-wise chattering     (5.37)
    N_h(c; 0, S) = sum over the 2^m sign patterns s of N(s o c; 0, S)       half-normal (5.39)-(5.42)
    f_i = N(e^i; 0, S) N_h(C^i; 0, S)                                                           (5.54)
    a   = lambda P_G (1 - P_D P_G) / (P_D V_c),   V_c = V - 2^m det(Psi) = V - prod_j 2 psi_j    (5.54)
    beta_i = f_i / (a + sum_l f_l),   beta_0 = a / (a + sum_l f_l)                              (5.53)

V is the gate volume (§4.1), V_c the part of the gate outside the boundary-layer box, where clutter is
uniform (5.52). A measurement inside the box (C = 0) gets N_h(0) = 2^m N(0), the largest value, so it is
preferred to a validated measurement outside the box (§5.5.3).

Two forms of the constants (`form`):
* "consistent" (default): a as above and the normalised half-normal density, prefactor
  1 / (pi sqrt|S|) for m = 2. Substituting (5.49), (5.50) and (5.52) into (5.47) gives exactly this a
  [R]; the folded normal of (5.39) integrates to 1 only with this prefactor [R].
* "thesis": the constants as printed, a = lambda P_G (1 - P_D P_G) / V_c (no 1/P_D) and
  N_h with prefactor 1 / (4 pi sqrt|S|) in (5.40)-(5.42), i.e. 2^-m times the sum above (generalised
  to m != 2 the same way). Relative to "consistent" the clutter hypothesis weighs 2^m P_D times more.
The default is the corrected form: "thesis" is faithful to the printed equations, but the printed a and
prefactor are not what (5.47)-(5.52) give, and only the corrected form is a probability model (e.g. with P_D -> 0 the printed a stays finite,
so measurements keep weight for a target that cannot be detected). The printed "2 m_{k+1}" in a is read
as 2^{n_z} in both forms (the box volume of (5.52)), and the (V - det Psi) of the printed i = 0 branch of
(5.52) as the same V_c [R].

When the augmentation is not used and plain PDA weights (§4.2, `pda`) are returned instead:
* §5.5.3 / (5.63): the gate ellipsoid lies inside the boundary-layer box, so no validated measurement
  can chatter. (5.63) states this with the eigenvalues of S and of B = (P^11)^-1 diag(E_z), which an
  associator does not see; the exact test used here is: the gate's half extent along axis j,
  sqrt(alpha S_jj), is at most psi_j for every j [R];
* §6.5: no validated measurement has C^i != 0 (no chattering information in this scan) [D];
* §6.5: V_c <= 0 (the box is larger than the gate volume, so (5.52) has no clutter region) [D];
* P_D = 0 (the consistent a is infinite; the track cannot be detected) [D].

Diagnostics returned per track: chattering = max over validated measurements of ||C^i||_2 [m];
chattering_n = number of validated measurements with C^i != 0; apda_active = 1 if (5.53) was used.
"""

from __future__ import annotations

import itertools
import math

import numpy as np

from roadtrack.trackers.association.logsum import logsumexp
from roadtrack.trackers.association.params import AssociationParams
from roadtrack.trackers.association.pda import pda

FORMS = ("consistent", "thesis")
LAYER_MODES = ("filter", "saturated")


def log_half_normal(C: np.ndarray, S: np.ndarray, form: str = "consistent") -> np.ndarray:
    """log N_h(C; 0, S) (5.39)-(5.42): C (T, M, m) >= 0, S (T, m, m) or per pair (T, M, m, m) -> (T, M). "consistent": the sum of
    N(s o C; 0, S) over the 2^m sign patterns s (a density on the positive orthant); "thesis": 2^-m times it
    (the printed 1 / (4 pi sqrt|S|) for m = 2)."""
    T, M, m = C.shape
    Sinv = np.linalg.inv(S)
    _, logdet = np.linalg.slogdet(S)
    signs = np.array(list(itertools.product((1.0, -1.0), repeat=m)))  # (2^m, m)
    x = signs[None, :, None, :] * C[:, None, :, :]  # (T, 2^m, M, m)
    if S.ndim == 4:  # one S per (track, measurement) pair, (T, M, m, m): measurements with their own R
        q = np.einsum("tsjm,tjmn,tsjn->tsj", x, Sinv, x)
        logdet = logdet[:, None, :]
    else:
        q = np.einsum("tsjm,tmn,tsjn->tsj", x, Sinv, x)
        logdet = logdet[:, None, None]
    log_n = -0.5 * q - 0.5 * (m * math.log(2.0 * math.pi) + logdet)  # log N(s o C; 0, S)
    out = logsumexp(log_n, axis=1)  # (5.39) sum over sign patterns
    return out - m * math.log(2.0) if form == "thesis" else out  # (5.40)-(5.42) printed 1/(4 pi sqrt|S|)


def apda(nu: np.ndarray, S: np.ndarray, log_lik: np.ndarray, gated: np.ndarray, layers: np.ndarray,
         gate_volume: np.ndarray, pd: np.ndarray, pg: float, clutter_density: float, alpha: float, *,
         form: str = "consistent", psi_max: float = 2.0,
         layer_mode: str = "filter", S_pairs: np.ndarray | None = None
         ) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
    """APDA weights (W (T, M), w0 (T,), diagnostics) from innovations nu (T, M, m), S (T, m, m), log N(nu; 0, S)
    (T, M), gate flags (T, M), boundary layers (T, m) (NaN rows: none, psi_max used), gate volumes V (T,),
    per-track P_D (T,), P_G, lambda [1/m^m] and the gate threshold alpha. layer_mode "saturated" uses
    min(layer, psi_max) (§6.5 effective layer [D]). S_pairs (T, M, m, m): the per-detection S of measurements with
    their own covariances (in the half-normal term; the gate extent stays the track's S), or None. See module
    docstring."""
    if form not in FORMS:
        raise ValueError(f"APDA form must be one of {list(FORMS)}, got {form!r}")
    if layer_mode not in LAYER_MODES:
        raise ValueError(f"APDA layer mode must be one of {list(LAYER_MODES)}, got {layer_mode!r}")
    T, M = gated.shape
    m = nu.shape[-1]
    pd = np.broadcast_to(np.asarray(pd, dtype=np.float64), (T,))
    W, w0 = pda(log_lik, gated, AssociationParams(pd=1.0, pg=pg, clutter_density=clutter_density), pd)  # (4.13)
    psi = np.where(np.isnan(layers), psi_max, layers).reshape(T, m)
    if layer_mode == "saturated":
        psi = np.minimum(psi, psi_max)
    if not (np.isfinite(psi).all() and (psi >= 0).all()):
        raise ValueError("APDA boundary layers must be finite and >= 0")
    C = np.maximum(0.0, np.abs(nu) - psi[:, None, :])  # (5.37) chattering magnitude
    chatters = gated & (C > 0).any(axis=2)
    norm = np.where(gated, np.sqrt((C * C).sum(axis=2)), 0.0)
    info = {"chattering": norm.max(axis=1, initial=0.0), "chattering_n": chatters.sum(axis=1).astype(np.float64)}
    half_extent = np.sqrt(alpha * np.diagonal(S, axis1=1, axis2=2))  # gate ellipsoid along each axis
    v_c = gate_volume - np.prod(2.0 * psi, axis=1)  # (5.52) V - 2^{n_z} det(Psi)
    active = (half_extent > psi).any(axis=1) & chatters.any(axis=1) & (v_c > 0) & (pd > 0)  # §5.5.3, §6.5
    info["apda_active"] = active.astype(np.float64)
    if not active.any():
        return W, w0, info
    t = np.flatnonzero(active)
    S_f = S[t] if S_pairs is None else S_pairs[t]
    log_f = np.where(gated[t], log_lik[t] + log_half_normal(C[t], S_f, form), -np.inf)  # (5.54) f_i
    with np.errstate(divide="ignore"):
        log_a = (math.log(clutter_density) + math.log(pg) + np.log1p(-pd[t] * pg)
                 - np.log(v_c[t]))  # (5.54) a, printed form
    if form == "consistent":
        log_a = log_a - np.log(pd[t])  # (5.54) a from (5.47)-(5.52): the 1/P_D the printed a lacks [R]
    terms = np.concatenate([log_a[:, None], log_f], axis=1)
    prob = np.exp(terms - logsumexp(terms, axis=1, keepdims=True))  # (5.53)
    w0[t], W[t] = prob[:, 0], prob[:, 1:]
    return W, w0, info
