"""The filter contract, the shared model-based predict, and the PDA-form helpers every filter uses.

A filter is a frozen dataclass holding its models (`motion`, `measurement`, see trackers.models) and
parameters, with stateless methods:

    initial_state(x0, P0)          -> FilterState   from a kinematic Gaussian [p; v] (2d,), (2d, 2d)
    predict(s, dt)                 -> FilterState   prior at the next scan (stores the Jacobian F used)
    predicted_measurement(s_pred)  -> (z_hat (m,), S (m, m))
    update(s_pred, nu, beta, beta0)-> FilterState   PDA-form update (thesis §4.2/§4.3)
    output(s)                      -> (x, P)        estimate in `motion`'s layout (IMM: combined)
    layer(s_pred)                  -> (m,) or None  boundary-layer half widths in measurement space
                                                    (SVSF family; read by APDA and drawn by the viewer)

`update` takes the innovations nu (M, m) of the measurements a track may use, their association
weights beta (M,) and the miss weight beta0, with beta0 + sum(beta) = 1; optionally `R` (M, m, m), the
measurements' own covariances (the built-in filters take it; the tracker passes it when the measurement model
says `per_detection` and the update has the keyword, `takes_detection_R`). Hard association (NN, GNN)
is beta = [1], beta0 = 0; PDA and JPDA pass soft weights. M = 0 or beta0 = 1 returns the prediction.
An SVSF-family filter sets e_{z,k|k-1} to the combined innovation (2.27), computes its own gain (reading
dt and the partition of `s_pred.F`), combines the covariance with `pda_covariance` (4.16)-(4.17) and
stores e_{z,k|k} (3.65) in `e_post`. Per-track diagnostics go into `FilterState.info` (a dict of
scalars or (m,) arrays); the tracker adds NIS and association quantities and the testbed logs them.
An IMM returns a `FilterState` subclass whose x, P are the combined output and whose extra fields
carry the mode-matched states.
"""

from __future__ import annotations

import functools
import inspect
import math
from dataclasses import replace
from typing import Protocol, runtime_checkable

import numpy as np

from roadtrack.trackers.errors import FilterError
from roadtrack.trackers.state import FilterState, StateRows, derive, derive_frozen, freeze, frozen_state, rows_of


@runtime_checkable
class Filter(Protocol):
    motion: object
    measurement: object

    def initial_state(self, x0: np.ndarray, P0: np.ndarray) -> FilterState: ...

    def predict(self, s: FilterState, dt: float) -> FilterState: ...

    def predicted_measurement(self, s_pred: FilterState) -> tuple[np.ndarray, np.ndarray]: ...

    def update(self, s_pred: FilterState, nu: np.ndarray, beta: np.ndarray, beta0: float) -> FilterState: ...

    def output(self, s: FilterState) -> tuple[np.ndarray, np.ndarray]: ...

    def layer(self, s_pred: FilterState) -> np.ndarray | None: ...


class ModelFilter:
    """Shared parts of every single-model filter (KF, EKF, the SVSF family): `self.motion` and
    `self.measurement` models. Predict is the (E)KF predict; subclasses write `update`."""

    motion: object
    measurement: object

    def initial_state(self, x0: np.ndarray, P0: np.ndarray) -> FilterState:
        x, P = self.motion.embed(x0, P0)
        return FilterState(x=x, P=P, e_post=np.zeros(self.measurement.ndim))  # §7.2: SVSF memory e_{z,0|0} = 0

    def predict(self, s: FilterState, dt: float) -> FilterState:
        """Prior after `dt` seconds (dt >= 0): x = f(x), P = F P F^T + Q (4.24), (4.26); F kept in the state."""
        dt = float(dt)
        if not math.isfinite(dt) or dt < 0:
            raise ValueError(f"predict needs a finite dt >= 0, got {dt}")
        F = self.motion.jacobian(s.x, dt)
        x = self.motion.f(s.x, dt)  # (4.3)-(4.8), (4.24) predict; EKF (1.11) for a nonlinear f
        P = symmetrise(F @ s.P @ F.T + self.motion.process_noise(dt, s.x))  # (4.26), Q = G Qv G^T (§1.1 [R])
        check_covariance(P, "predicted covariance P")
        return replace(s, x=x, P=P, F=F, info={})

    def measurement_jacobian(self, s_pred: FilterState) -> np.ndarray:
        return self.measurement.jacobian(s_pred.x, self.motion)

    def predicted_measurement(self, s_pred: FilterState) -> tuple[np.ndarray, np.ndarray]:
        """z_hat = h(x) (m,), S = H P H^T + R (m, m)."""
        H = self.measurement_jacobian(s_pred)
        S = symmetrise(H @ s_pred.P @ H.T + self.measurement.R)  # (4.3)-(4.8) innovation covariance S
        return self.measurement.h(s_pred.x, self.motion), S

    def output(self, s: FilterState) -> tuple[np.ndarray, np.ndarray]:
        return s.x, s.P

    def layer(self, s_pred: FilterState) -> np.ndarray | None:
        return None

    @property
    def layered(self) -> bool:
        """False if `layer` is ModelFilter's (None for every state): the tracker then skips the per-track calls."""
        return type(self).layer is not ModelFilter.layer

    # Batched forms used by the tracker; a filter may override them with vectorised code (the KF does).
    def predict_many(self, states: list[FilterState], dt: float) -> list[FilterState]:
        """`predict` of T tracks at once: vectorised for a linear motion model or one with `f_many` and
        `jacobian_many` (the CT model), else the per-track loop."""
        dt = float(dt)
        if not math.isfinite(dt) or dt < 0:
            raise ValueError(f"predict needs a finite dt >= 0, got {dt}")
        if not states or not self.predicts_arrays():
            return [self.predict(s, dt) for s in states]  # a subclass's own predict is its reference
        X, P, F = self.predict_arrays(rows_of(states, "x"), rows_of(states, "P"), dt)
        Fs = [F] * len(states) if F.ndim == 2 else F
        return StateRows([frozen_state(x, p, s.e_post, f, {}) if type(s) is FilterState
                          else derive_frozen(s, x=x, P=p, F=f, info={}) for s, x, p, f in zip(states, X, P, Fs)], x=X, P=P)

    def predicts_arrays(self) -> bool:
        """True if `predict_arrays` is this filter's predict: its class keeps ModelFilter's predict and its motion
        model is linear or has `f_many` and `jacobian_many`."""
        return type(self).predict is ModelFilter.predict and (
            self.motion.linear or (hasattr(self.motion, "f_many") and hasattr(self.motion, "jacobian_many")))

    def predict_arrays(self, X: np.ndarray, P: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """`predict` on stacked states X (T, n), P (T, n, n) (dt >= 0 checked by the caller): the predicted X, P and
        the transition Jacobian F, (n, n) for a linear model or (T, n, n), all read-only."""
        if self.motion.linear:
            A, Q = self.motion.transition(dt), self.motion.process_noise(dt)
            Xn = X @ A.T  # (4.24) x = A x
            P = A @ P @ A.T + Q  # (4.26) P = A P A^T + Q
            F = A
        else:
            if hasattr(self.motion, "f_and_jacobian_many"):  # both from one pass over the tracks (the CT model)
                Xn, F = self.motion.f_and_jacobian_many(X, dt)  # (4.24) predict and the EKF (1.11) Jacobians
            else:
                F = self.motion.jacobian_many(X, dt)  # (T, n, n), the EKF (1.11) Jacobians
                Xn = self.motion.f_many(X, dt)  # (4.24) predict, EKF (1.11) for a nonlinear f
            P = F @ P @ np.swapaxes(F, 1, 2) + self.motion.process_noise(dt)  # (4.26)
        P = 0.5 * (P + np.swapaxes(P, 1, 2))
        check_covariance(P, "predicted covariance P")
        freeze(Xn, P, F)
        return Xn, P, F

    def predicted_measurements(self, preds: list[FilterState]) -> tuple[np.ndarray, np.ndarray]:
        """z_hat (T, m) and S (T, m, m) of T predicted states: vectorised for a linear measurement model, else
        (or for a subclass with its own predicted_measurement or measurement_jacobian) the per-track loop."""
        own = (type(self).predicted_measurement is not ModelFilter.predicted_measurement
               or type(self).measurement_jacobian is not ModelFilter.measurement_jacobian)
        if preds and self.measurement.linear and not own:
            return self.linear_predicted_measurements(preds)
        m = self.measurement.ndim
        zs = [self.predicted_measurement(s) for s in preds]
        return (np.array([z for z, _ in zs], dtype=np.float64).reshape(len(preds), m),
                np.array([S for _, S in zs], dtype=np.float64).reshape(len(preds), m, m))

    def linear_predicted_measurements(self, preds: list[FilterState]) -> tuple[np.ndarray, np.ndarray]:
        """z_hat = H x (T, m), S = H P H^T + R (T, m, m) of T >= 1 predicted states (H: the linear measurement's)."""
        H = self.measurement.matrix(self.motion)
        S = H @ rows_of(preds, "P") @ H.T + self.measurement.R  # (4.3)-(4.8) innovation covariance S
        return rows_of(preds, "x") @ H.T, 0.5 * (S + np.swapaxes(S, 1, 2))

    def update_many(self, preds: list[FilterState], nu: np.ndarray, W: np.ndarray,
                    w0: np.ndarray, R: np.ndarray | None = None) -> list[FilterState]:
        """PDA-form updates of T tracks: nu (T, M, m) innovations, W (T, M) weights, w0 (T,) miss weights; R (M, m, m)
        the detections' own covariances or None (the measurement model's R)."""
        out = []
        for t, s in enumerate(preds):
            use = W[t] > 0.0
            if R is None:
                out.append(self.update(s, nu[t, use], W[t, use], float(w0[t])))
            else:
                out.append(self.update(s, nu[t, use], W[t, use], float(w0[t]), R=R[use]))
        return out


    # Road-map hooks (trackers/road.py): a known input added to the prediction and a scalar pseudo-measurement.
    def shift_many(self, states: list[FilterState], dkin: np.ndarray, spread: bool = False) -> list[FilterState]:
        """States with [px, py, vx, vy] moved by dkin (T, 4) (a known input B u, trackers.road), and with
        ``spread`` their covariance on those entries grown by dkin dkin^T (the input uncertain by its own size):
        for a linear motion model with 2-D positions and velocities; any other model's states are returned
        unchanged."""
        mot = self.motion
        if not states or not mot.linear or len(mot.position) < 2 or len(mot.velocity) < 2:
            return list(states)
        idx = list(mot.position[:2]) + list(mot.velocity[:2])
        X = np.array(rows_of(states, "x"))  # a copy, rows shifted below
        X[:, idx] += dkin  # x + B u
        moved = (dkin.any(axis=1) if spread else np.zeros(len(states), dtype=bool)).tolist()
        P = rows_of(states, "P")
        if any(moved):  # a straight lane (u = 0) adds nothing: no copy on the hot path
            P, rows = np.array(P), np.flatnonzero(moved)
            d = dkin[rows]
            P[np.ix_(rows, idx, idx)] += d[:, :, None] * d[:, None, :]  # Q_u = B Sigma_u B^T, Sigma_u = u u^T [D]
        freeze(X, P)
        return StateRows([derive_frozen(s, x=x, P=p) if m else derive_frozen(s, x=x)
                          for s, x, p, m in zip(states, X, P, moved)], X, P,
                         states.e_post if type(states) is StateRows else None)

    def pseudo_update_many(self, states: list[FilterState], h: np.ndarray, y: np.ndarray,
                           r: np.ndarray) -> list[FilterState]:
        """Scalar Kalman updates of T states with the pseudo-measurement rows h (T, 2) on the 2-D position,
        innovations y (T,) and variances r (T,) > 0 (trackers.road lane keeping): x + K y, Joseph-form P."""
        pos = list(self.motion.position[:2])
        out = []
        for s, hp, yt, rt in zip(states, h, y, r):
            H = np.zeros(len(s.x))
            H[pos] = hp
            PH = s.P @ H
            K = PH / (H @ PH + rt)  # Kalman gain of a scalar measurement, §1.1 (1.6)
            I_KH = identity(len(s.x)) - np.outer(K, H)
            P = symmetrise(I_KH @ s.P @ I_KH.T + rt * np.outer(K, K))  # Joseph form, §1.1 (1.8)
            out.append(derive(s, x=s.x + K * yt, P=check_covariance(P, "lane-kept covariance P")))
        return out


@functools.lru_cache(maxsize=16)
def identity(n: int) -> np.ndarray:
    """The identity I (n, n), read-only, made once per size (np.eye's wrapper costs more than the Joseph form's
    subtraction it feeds)."""
    return _read_only(np.eye(n))


@functools.lru_cache(maxsize=16)
def zeros(n: int) -> np.ndarray:
    """A zero vector (n,), read-only, made once per size (shared, e.g. by the tracker's candidates' memories)."""
    return _read_only(np.zeros(n))


def _read_only(a: np.ndarray) -> np.ndarray:
    a.setflags(write=False)
    return a


def batch_predict(filter_, states: list[FilterState], dt: float) -> list[FilterState]:
    """`predict_many` of any filter (the per-track loop for filters without one)."""
    many = getattr(filter_, "predict_many", None)
    return many(states, dt) if many is not None else [filter_.predict(s, dt) for s in states]


def batch_layers(filter_, states: list[FilterState], m: int) -> np.ndarray:
    """Boundary-layer half widths (T, m) of T predicted states (`layer`), NaN rows where a state has none: the
    filter's `layers_many` when it has one (the same rows at once), else per track; no per-track call for a filter
    whose `layered` is False (every layer None)."""
    layers = np.full((len(states), m), np.nan)
    if not getattr(filter_, "layered", True) or not states:
        return layers
    many = getattr(filter_, "layers_many", None)
    if many is not None:
        return many(states, m)
    for t, s in enumerate(states):
        lay = filter_.layer(s)
        if lay is not None:
            layers[t] = lay
    return layers


def batch_predicted_measurements(filter_, preds: list[FilterState]) -> tuple[np.ndarray, np.ndarray]:
    many = getattr(filter_, "predicted_measurements", None)
    if many is not None:
        return many(preds)
    return ModelFilter.predicted_measurements(filter_, preds)


def batch_update(filter_, preds: list[FilterState], nu: np.ndarray, W: np.ndarray, w0: np.ndarray,
                 R: np.ndarray | None = None, log_lik: np.ndarray | None = None) -> list:
    """`update_many` of any filter (the per-track loop for filters without one); R (M, m, m): the detections' own
    covariances, passed only when given (a filter that takes them: `takes_detection_R`); log_lik (T, M): log N(nu; 0,
    S) of every (track, measurement) pair as the association computed it (trackers.gating), passed only when given
    and the filter's `update_many` has the keyword (the IMM reads its N_c there instead of computing it again)."""
    many = getattr(filter_, "update_many", None)
    if many is None:
        many = lambda *a, **k: ModelFilter.update_many(filter_, *a, **k)  # noqa: E731
    kw = {} if R is None else {"R": R}
    if log_lik is not None and _update_many_takes(type(filter_), "log_lik"):
        kw["log_lik"] = log_lik
    return many(preds, nu, W, w0, **kw)


@functools.lru_cache(maxsize=None)
def _update_many_takes(cls: type, name: str) -> bool:
    method = getattr(cls, "update_many", None)
    return method is not None and name in inspect.signature(method).parameters


def takes_detection_R(filter_) -> bool:
    """True if the filter's measurement model asks for the detections' own covariances (``per_detection``) and its
    update takes them (an ``R`` keyword of ``update``, and of ``update_many`` when it has one)."""
    if not getattr(getattr(filter_, "measurement", None), "per_detection", False):
        return False
    return _update_takes_R(type(filter_))


@functools.lru_cache(maxsize=None)
def _update_takes_R(cls: type) -> bool:
    methods = [getattr(cls, "update", None), getattr(cls, "update_many", None)]
    return methods[0] is not None and all(f is None or "R" in inspect.signature(f).parameters for f in methods)


def pair_covariances(S: np.ndarray, R: np.ndarray, R0: np.ndarray) -> np.ndarray:
    """Innovation covariances of every (track, detection) pair, S_tj = S_t - R0 + R_j (T, M, m, m): S (T, m, m)
    computed with the fixed R0 (m, m), R (M, m, m) the detections' own (thesis §4.1: S = H P H^T + R, per
    detection)."""
    return S[:, None, :, :] + (R - R0)[None, :, :, :]


def weighted_R(R: np.ndarray, W: np.ndarray) -> np.ndarray:
    """Association-weighted mean detection covariance sum_j W_tj R_j / sum_j W_tj (T, m, m) of R (M, m, m) and
    weights W (T, M) >= 0 (a row of zeros gives the plain mean; a single weight gives that detection's R)."""
    w = np.asarray(W, dtype=np.float64)
    tot = w.sum(axis=1, keepdims=True)
    w = np.where(tot > 0.0, w / np.where(tot > 0.0, tot, 1.0), 1.0 / max(w.shape[1], 1))
    return np.einsum("tj,jab->tab", w, R)


def weighted_outer(W: np.ndarray, D: np.ndarray) -> np.ndarray:
    """sum_j W_aj D_aj D_aj^T (A, k, k) of weights W (A, M) >= 0 and rows D (A, M, k) (the PDA spread term of
    (4.17)): np.einsum("aj,aji,ajk->aik", W, D, D) over each track's entries with W > 0 only, in their order and
    zero-padded to the longest row. einsum adds a pair's terms one j after the other and an entry with W = 0 adds an
    exact zero, so the sums are the full einsum's bit for bit (tests/test_trackers_filters.py), without its loop over
    every (track, measurement) pair (a few measurements of the M in a scan are a track's)."""
    use = W > 0.0
    A, M = use.shape
    counts = use.sum(axis=1)
    K = int(counts.max()) if A else 0
    if 2 * K > M:  # little to drop: the einsum as it is
        return np.einsum("aj,aji,ajk->aik", W, D, D)
    rows, cols = np.nonzero(use)  # row by row, each row's entries in order
    pos = np.arange(rows.size) - (np.cumsum(counts) - counts)[rows]  # an entry's place within its row
    cW = np.zeros((A, K))
    cW[rows, pos] = W[rows, cols]
    cD = np.zeros((A, K, D.shape[2]))
    cD[rows, pos] = D[rows, cols]
    return np.einsum("aj,aji,ajk->aik", cW, cD, cD)


def sum_in_order(terms: list[np.ndarray]) -> np.ndarray:
    """(((0 + t_0) + t_1) + ...) of arrays of one shape: the terms added one after the other into zeros. np.einsum
    adds the products of a contracted axis of length <= 2 this way, so such an einsum written as its products summed
    here gives its bits exactly, signed zeros included (tests/test_trackers_filters.py checks the form used against
    einsum). Where einsum's iterator is slow (a short contracted innermost axis and a long output: 250 us for
    (45, 53, 2) x (45, 4, 2)), these few whole-array operations are much faster."""
    out = 0.0 + terms[0]
    for t in terms[1:]:
        out = out + t
    return out


def check_detection_R(R, M: int, m: int) -> np.ndarray:
    """R as float64 (M, m, m), or ValueError (one line) unless every R_j is finite, symmetric and positive
    definite."""
    R = np.asarray(R, dtype=np.float64)
    if R.shape != (M, m, m):
        raise ValueError(f"detection covariances R must be ({M}, {m}, {m}) for {M} detections, got {R.shape}")
    if not np.isfinite(R).all():
        j = int(np.flatnonzero(~np.isfinite(R).reshape(M, -1).all(axis=1))[0])
        raise ValueError(f"detection {j}'s covariance R is not finite")
    if M and np.abs(R - np.swapaxes(R, 1, 2)).max() > 1e-9 * max(1.0, float(np.abs(R).max())):
        raise ValueError("detection covariances R must be symmetric")
    if M and (np.linalg.eigvalsh(R)[:, 0] <= 0.0).any():
        j = int(np.flatnonzero(np.linalg.eigvalsh(R)[:, 0] <= 0.0)[0])
        raise ValueError(f"detection {j}'s covariance R is not positive definite")
    return R


def symmetrise(P: np.ndarray) -> np.ndarray:
    """(P + P^T) / 2."""
    return 0.5 * (P + P.T)


def check_covariance(P: np.ndarray, what: str) -> np.ndarray:
    """Return P if finite, else raise FilterError naming `what`."""
    if not np.isfinite(P).all():
        raise FilterError(f"{what} is not finite")
    return P


def cholesky(S: np.ndarray, what: str) -> np.ndarray:
    """Lower Cholesky factor of S, or FilterError (one line) if S is non-finite or not positive definite."""
    check_covariance(S, what)
    try:
        return np.linalg.cholesky(S)
    except np.linalg.LinAlgError:
        raise FilterError(f"{what} is not positive definite (eigenvalues {np.linalg.eigvalsh(S)})") from None


def check_weights(nu: np.ndarray, beta: np.ndarray, beta0: float, m: int) -> tuple[np.ndarray, np.ndarray, float]:
    """Validate PDA-form update inputs: nu (M, m), beta (M,) >= 0, beta0 in [0, 1], beta0 + sum(beta) = 1."""
    nu = np.asarray(nu, dtype=np.float64)
    beta = np.asarray(beta, dtype=np.float64)
    beta0 = float(beta0)
    if nu.size == 0:
        nu = nu.reshape(0, m)
    if nu.ndim != 2 or nu.shape[1] != m or beta.shape != (nu.shape[0],):
        raise ValueError(f"update needs nu (M, {m}) and beta (M,), got nu {nu.shape} and beta {beta.shape}")
    if not (np.isfinite(nu).all() and np.isfinite(beta).all() and np.isfinite(beta0)):
        raise ValueError("update got non-finite innovations or weights")
    if beta0 < 0.0 or beta0 > 1.0 or np.any(beta < 0.0) or abs(beta0 + beta.sum() - 1.0) > 1e-9:
        raise ValueError(f"update weights must be >= 0 and sum to 1: beta0={beta0}, sum(beta)={beta.sum()}")
    return nu, beta, beta0


def batch_weights(nu: np.ndarray, W: np.ndarray, w0: np.ndarray, active: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`check_weights` of the active tracks of a batched update: (nu (A, M, m) with the ungated entries zeroed,
    W (A, M), w0 (A,)) of the rows ``active`` (A,) of nu (T, M, m), W (T, M), w0 (T,); ValueError as the
    per-track check (non-finite values, negative weights, rows not summing to 1)."""
    Wa, b0 = np.asarray(W[active], dtype=np.float64), np.asarray(w0[active], dtype=np.float64)
    nua = np.where((Wa > 0.0)[..., None], nu[active], 0.0)  # what the per-track update is given
    if not (np.isfinite(nua).all() and np.isfinite(Wa).all() and np.isfinite(b0).all()):
        raise ValueError("update got non-finite innovations or weights")
    if (Wa < 0.0).any() or (b0 < 0.0).any() or (np.abs(b0 + Wa.sum(axis=1) - 1.0) > 1e-9).any():
        raise ValueError("update weights must be >= 0 and sum to 1")
    return nua, Wa, b0


def combined_innovation(nu: np.ndarray, beta: np.ndarray) -> np.ndarray:
    """Combined innovation sum_i beta_i nu_i (m,)."""
    return beta @ nu  # (4.15) combined innovation


def pda_covariance(P_pred: np.ndarray, P_star: np.ndarray, K: np.ndarray, nu: np.ndarray, beta: np.ndarray,
                   beta0: float) -> np.ndarray:
    """PDA posterior covariance beta0 P_pred + (1 - beta0) P* + K [sum beta_i nu_i nu_i^T - nu_c nu_c^T] K^T.

    P_pred, P_star (n, n); K (n, m) the filter's gain; nu (M, m); beta (M,). Returns a symmetric (n, n)."""
    nu_c = combined_innovation(nu, beta)
    spread = (nu.T * beta) @ nu - np.outer(nu_c, nu_c)
    P_tilde = K @ spread @ K.T  # (4.17) spread of innovations
    return symmetrise(beta0 * P_pred + (1.0 - beta0) * P_star + P_tilde)  # (4.16) PDA covariance
