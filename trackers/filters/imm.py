"""Interacting multiple model (IMM) filter over any registered single-model filters (thesis §1.3.2.3
(1.13)-(1.18), §2.3.4 (2.101)-(2.106)). Tags: [D] a choice the thesis leaves open, made here.

One cycle, with p_ji = P{mode j at k-1 -> mode i at k} (the Markov matrix `transition[j, i]`, per scan,
rows sum to 1) and r modes:

  predict(s, dt)       mixing (2.101)-(2.102) at the START of the cycle, then each mode's own predict.
                       c_i = sum_j p_ji mu_j, mu_{j|i} = p_ji mu_j / c_i, x_0i = sum_j mu_{j|i} x_j,
                       P_0i = sum_j mu_{j|i} [P_j + (x_j - x_0i)(x_j - x_0i)^T]. The SVSF memories e_post are
                       mixed with the same weights [D]; other fields of a mode's state stay
                       the mode's own. The predicted state carries mu = c (predicted mode probabilities).
  predicted_measurement  moment matching of the modes' (z_i, S_i) with weights c:
                       z_c = sum_i c_i z_i, S_c = sum_i c_i [S_i + (z_i - z_c)(z_i - z_c)^T]. The tracker gates
                       and associates ONCE per track on N_c = N(z_c, S_c): all modes share that gate and the
                       same validated measurements [D] (the thesis requires one validated set for all modes, §2.3.4).
  update(s, nu, b, b0) each mode gets the same weights and its own innovations z_j - z_i; mode likelihood
                       (2.103), mode probabilities (2.104), output (1.17)-(1.18).

Mode likelihood from association weights. With L_j = P_D N_c(z_j) / lambda, D = (1 - P_D P_G) + sum_j L_j,
beta_j = L_j / D and beta_0 = (1 - P_D P_G) / D (PDA, trackers.association.pda), the thesis likelihood
    (2.103) Lambda_i = lambda (1 - P_D P_G) + P_D sum_j N_i(z_j) = lambda D [beta_0 + sum_j beta_j N_i(z_j) / N_c(z_j)],
and lambda D is the same for every mode, so it cancels in (2.104). The IMM therefore needs only the weights:
Lambda_i ∝ beta_0 + sum_j beta_j N_i(z_j) / N_c(z_j), exact for PDA (whatever miss term the associator uses,
the identity returns (2.103) with that term); for hard association (NN, GNN: beta = [1]) it is N_i / N_c, the
standard IMM likelihood; for JPDA's marginal weights it is the natural approximation. No measurement (or
beta_0 = 1) gives Lambda_i equal for all modes: update returns the prediction, whose mu is c, after each mode's
own miss handling (an SVSF-family mode with memory_after_miss = "reset" zeroes its memory).

Mixed mode banks (a 4-D NCV mode beside a 5-D CT mode, [D]: the thesis does not say how §2.3.5's two models meet): every mode state starts with the
kinematic [p; v]. Mixing into a smaller mode drops the extra entries (omega); mixing into a larger one pads
with the target mode's `motion.embed` (CT: omega = 0 with variance omega_std0^2, default (0.1 rad/s)^2,
set per mode as `modes[i].omega_std0`). The combined output (1.17)-(1.18) is in the largest mode's layout
(the first largest if several), padded the same way; it is output only, not part of the recursion.

Parameters (IMMParams): `modes` are filter tables built with `build_filter` (errors name
"filter.modes[1].sigma_v"); shared `sigma_v` / `sigma_w`, when given, fill every mode table that has the
key and does not set it; `transition` and `mu0` default to 0.95 on the diagonal and [0.9, 0.1] [D] (the thesis gives no values).
Diagnostics (`FilterState.info`, logged by the tracker): "mu" (r,) in the order of `IMMFilter.mode_names`,
and each mode's own info as "<mode name>.<key>" (e.g. "ct.psi_z").

Batched forms (what the tracker calls, through filters.base.batch_*): `predict_many`, `predicted_measurements`
and `update_many` run the same cycle over T tracks at once, the mixing, moment matching, mode likelihoods and
mode probabilities vectorised over tracks and each mode's predict / update by that mode filter's own batched
form. The per-track `predict` / `predicted_measurement` / `update` are their reference (equal to 1e-12,
tests/test_trackers_imm.py). They return an `IMMRows` list (the states with their mode probabilities and per mode
the StateRows of their mode states), from which the scan's next batched call reads the stacked rows, and the update
reuses the predicted mode measurements of the same states.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from roadtrack.trackers.filters.base import (ModelFilter, batch_layers, batch_predict, batch_predicted_measurements,
                                   batch_update, check_covariance, check_weights, pair_covariances, symmetrise)
from roadtrack.trackers.filters.gvbl import GVBLState, gvbl_state
from roadtrack.trackers.gating import log_gaussian
from roadtrack.trackers.models import MOTION_MODELS
from roadtrack.trackers.params import NON_NEGATIVE, POSITIVE, ParamError, param
from roadtrack.trackers.state import (FilterState, StateRows, derive, derive_frozen, freeze, frozen_state, rows_of,
                                     take_rows)


# --------------------------------------------------------------------------------------------- state
@dataclass(frozen=True, eq=False)
class IMMState(FilterState):
    """x (n,), P (n, n): the combined estimate (1.17)-(1.18) in the largest mode's layout; e_post: the
    mu-weighted mode memories; modes: the r mode-matched states, each in its own layout; mu (r,): mode
    probabilities (after predict the predicted ones c (2.101), after update mu_k (2.104))."""

    modes: tuple[FilterState, ...] = ()
    mu: np.ndarray = field(default_factory=lambda: np.ones(1))

    def __post_init__(self) -> None:
        super().__post_init__()
        mu = np.array(self.mu, dtype=np.float64)
        if mu.ndim != 1 or mu.size != len(self.modes):
            raise ValueError(f"IMMState.mu must be ({len(self.modes)},) for {len(self.modes)} modes, got {mu.shape}")
        mu.setflags(write=False)
        object.__setattr__(self, "mu", mu)
        object.__setattr__(self, "modes", tuple(self.modes))


def _imm_state(x: np.ndarray, P: np.ndarray, e_post: np.ndarray, info: dict, modes: tuple, mu: np.ndarray) -> IMMState:
    """IMMState(x, P, e_post, F=None, info, modes, mu) of read-only arrays without __init__, its fields set one by one
    in their declared order (state.frozen_state's way: half of derive_frozen's cost, T per scan and call)."""
    new = object.__new__(IMMState)
    d = new.__dict__
    d["x"], d["P"], d["e_post"], d["F"], d["info"], d["modes"], d["mu"] = x, P, e_post, None, info, modes, mu
    return new


# ------------------------------------------------------------------------------------------- helpers
def to_layout(s: FilterState, motion) -> tuple[np.ndarray, np.ndarray]:
    """A mode estimate (x, P) in `motion`'s layout: extra entries dropped, missing ones from `motion.embed`
    (CT: omega = 0, variance omega_std0^2; [D]) with zero cross-covariance."""
    n, k = motion.ndim, s.x.size
    if k >= n:
        return s.x[:n], s.P[:n, :n]  # [D]: drop omega when mixing into NCV
    kin = 2 * motion.dims
    x, P = motion.embed(s.x[:kin], s.P[:kin, :kin])  # [D]: pad omega = 0, var omega_std0^2
    x, P = np.array(x, dtype=np.float64), np.array(P, dtype=np.float64)
    x[:k], P[:k, :k] = s.x, s.P
    return x, P


def logsumexp(a: np.ndarray, axis: int | None = None, b: np.ndarray | None = None) -> np.ndarray:
    """log sum b exp(a) along `axis` (b >= 0): scipy.special.logsumexp's maths without its ~0.2 ms call
    overhead, which dominated the IMM cycle. All -inf (or all b = 0) gives -inf."""
    a = np.asarray(a, dtype=np.float64)
    if b is not None:
        with np.errstate(divide="ignore"):
            a = a + np.log(b)
    top = np.max(a, axis=axis, keepdims=True)
    top = np.where(np.isfinite(top), top, 0.0)
    with np.errstate(divide="ignore"):
        out = np.log(np.sum(np.exp(a - top), axis=axis, keepdims=True)) + top
    return out.squeeze(axis=axis) if axis is not None else out.reshape(())


def moments(xs: np.ndarray, Ps: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Moment-matched Gaussian of a mixture: xs (r, n), Ps (r, n, n), weights w (r,) summing to 1."""
    x = w @ xs
    d = xs - x
    P = np.einsum("j,jab->ab", w, Ps) + (d.T * w) @ d  # (2.102) / (1.18) mean covariance + spread of means
    return x, symmetrise(P)


def layout_many(X: np.ndarray, P: np.ndarray, motion) -> tuple[np.ndarray, np.ndarray]:
    """`to_layout` of T mode estimates at once: X (T, k), P (T, k, k) -> (T, n), (T, n, n) in `motion`'s layout
    (the model's `embed_many` pads, or its `embed` per track for a model without one)."""
    n, k = motion.ndim, X.shape[1]
    if k >= n:
        return X[:, :n], P[:, :n, :n]  # [D]: drop omega when mixing into NCV
    kin = 2 * motion.dims
    many = getattr(motion, "embed_many", None)
    if many is not None:
        Xn, Pn = many(X[:, :kin], P[:, :kin, :kin])  # [D]: pad omega = 0, var omega_std0^2
    else:
        pairs = [motion.embed(x[:kin], p[:kin, :kin]) for x, p in zip(X, P)]
        Xn, Pn = [a for a, _ in pairs], [b for _, b in pairs]
    Xn = np.array(Xn, dtype=np.float64).reshape(len(X), n)
    Pn = np.array(Pn, dtype=np.float64).reshape(len(X), n, n)
    Xn[:, :k], Pn[:, :k, :k] = X, P
    return Xn, Pn


def moments_many(xs: np.ndarray, Ps: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """`moments` of T mixtures at once: xs (T, r, n), Ps (T, r, n, n), weights w (T, r) (rows summing to 1)
    -> x (T, n), P (T, n, n) symmetric."""
    x = np.einsum("tj,tjn->tn", w, xs)
    d = xs - x[:, None, :]
    P = np.einsum("tj,tjab->tab", w, Ps) + np.swapaxes(d * w[:, :, None], 1, 2) @ d  # (2.102) / (1.18)
    return x, 0.5 * (P + np.swapaxes(P, 1, 2))


def stacked(states: list[FilterState]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """x (T, n), P (T, n, n), e_post (T, m) of T states of one layout (the rows a StateRows carries)."""
    return rows_of(states, "x"), rows_of(states, "P"), rows_of(states, "e_post")


class IMMRows(list):
    """T IMMStates made by one batched call (`IMMFilter._states_many`), with their mode probabilities mu (T, r) and,
    per mode i, the list of their mode states (mode_lists[i][t] is item t's modes[i]; a StateRows carrying the
    modes' x, P, e_post), so that the next batched call of the scan stacks nothing again. A copy or slice of it is a
    plain list."""

    def __init__(self, states, mu: np.ndarray, mode_lists: list):
        super().__init__(states)
        self.mu, self.mode_lists = mu, mode_lists
        self.measured: tuple | None = None  # (the states, zs, Ss, z_c, S_c) of predicted_measurements


# -------------------------------------------------------------------------------------------- filter
@dataclass(frozen=True, eq=False)
class IMMFilter:
    """IMM over `filters` (r mode-matched filters sharing one measurement model). transition (r, r):
    transition[j, i] = p_ji = P{mode j -> mode i} per scan (rows sum to 1); mu0 (r,) initial mode
    probabilities; mode_names (r,) labels (e.g. "cv", "ct"), in the order of `mu` and `info["mu"]`.
    See the module docstring for the cycle and the mode likelihood."""

    filters: tuple
    transition: np.ndarray
    mu0: np.ndarray
    mode_names: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        r = len(self.filters)
        if r < 1:
            raise ValueError("IMMFilter needs at least one mode filter")
        Pi = np.array(self.transition, dtype=np.float64)
        mu0 = np.array(self.mu0, dtype=np.float64)
        check_markov(Pi, mu0, r)
        Pi.setflags(write=False)
        mu0.setflags(write=False)
        object.__setattr__(self, "filters", tuple(self.filters))
        object.__setattr__(self, "transition", Pi)
        object.__setattr__(self, "mu0", mu0)
        names = tuple(self.mode_names) or default_mode_names(self.filters)
        if len(names) != r:
            raise ValueError(f"IMMFilter needs {r} mode names, got {len(names)}")
        object.__setattr__(self, "mode_names", names)
        m0 = self.filters[0]
        for i, f in enumerate(self.filters):
            if f.measurement != m0.measurement:
                raise ValueError(f"mode {i} measurement model {f.measurement} differs from mode 0's {m0.measurement}; "
                                 "all modes must share one")
            d = f.motion.dims
            if tuple(f.motion.position) != tuple(range(d)) or tuple(f.motion.velocity) != tuple(range(d, 2 * d)) \
                    or d != m0.motion.dims:
                raise ValueError(f"mode {i} state must start with the same [p; v] as mode 0 ({m0.motion.dims}-D)")
        object.__setattr__(self, "_big", int(np.argmax([f.motion.ndim for f in self.filters])))

    @property
    def motion(self):
        """The largest mode's motion model: the layout of x, P and `output`."""
        return self.filters[self._big].motion

    @property
    def measurement(self):
        return self.filters[0].measurement

    # -------------------------------------------------------------------- contract
    def initial_state(self, x0: np.ndarray, P0: np.ndarray) -> IMMState:
        """Every mode from the kinematic Gaussian (its own `embed`), mode probabilities mu0."""
        modes = tuple(f.initial_state(x0, P0) for f in self.filters)
        return self._state(modes, self.mu0)

    def predict(self, s: IMMState, dt: float) -> IMMState:
        """Mixing (2.101)-(2.102) with one Markov step per scan, then the mode-matched predictions."""
        with np.errstate(divide="ignore"):
            log_w = np.log(self.transition) + np.log(s.mu)[:, None]  # (r_j, r_i): log p_ji mu_j
        log_c = logsumexp(log_w, axis=0)  # (2.101) c_i = sum_j p_ji mu_j
        same_e = len({m.e_post.shape for m in s.modes}) == 1
        mixed = []
        for i, f in enumerate(self.filters):
            if not np.isfinite(log_c[i]):  # mode unreachable this scan: nothing to mix into it
                mixed.append(s.modes[i])
                continue
            w = np.exp(log_w[:, i] - log_c[i])  # (2.101) mixing probabilities mu_{j|i}
            xs, Ps = zip(*(to_layout(m, f.motion) for m in s.modes))
            x0, P0 = moments(np.array(xs), np.array(Ps), w)  # (2.102) mixed initial condition
            e0 = w @ np.array([m.e_post for m in s.modes]) if same_e else s.modes[i].e_post  # §5 [D] mixed memories
            mixed.append(replace(s.modes[i], x=x0, P=P0, e_post=e0))
        modes = tuple(f.predict(m, dt) for f, m in zip(self.filters, mixed))
        return self._state(modes, np.exp(log_c - logsumexp(log_c)))

    def mode_measurements(self, s_pred: IMMState) -> tuple[np.ndarray, np.ndarray]:
        """Each mode's predicted measurement and innovation covariance: z (r, m), S (r, m, m)."""
        zs, Ss = zip(*(f.predicted_measurement(m) for f, m in zip(self.filters, s_pred.modes)))
        return np.array(zs, dtype=np.float64), np.array(Ss, dtype=np.float64)

    def predicted_measurement(self, s_pred: IMMState) -> tuple[np.ndarray, np.ndarray]:
        """Moment-matched combined prediction z_c (m,), S_c (m, m) with the predicted mode probabilities."""
        return self._combine_measurements(*self.mode_measurements(s_pred), s_pred.mu)

    def update(self, s_pred: IMMState, nu: np.ndarray, beta: np.ndarray, beta0: float,
               R: np.ndarray | None = None) -> IMMState:
        """nu (M, m): innovations z_j - z_c relative to the combined prediction; beta (M,), beta0: the
        association weights computed from N_c. Mode-matched updates with the same weights, mode likelihoods
        Lambda_i ∝ beta0 + sum_j beta_j N_i(z_j) / N_c(z_j) (module docstring), (2.104), (1.17)-(1.18).
        R (M, m, m): the detections' own covariances (in N_i, N_c and every mode's update) or None."""
        meas = self.measurement
        nu, beta, beta0 = check_weights(nu, beta, beta0, meas.ndim)
        if nu.shape[0] == 0 or beta0 == 1.0:  # every Lambda_i equal: mu stays c
            modes = tuple(f.update(m, nu, beta, beta0) for f, m in zip(self.filters, s_pred.modes))
            if all(a is b for a, b in zip(modes, s_pred.modes)):
                return s_pred  # the modes keep their predictions
            return self._state(modes, s_pred.mu)  # a mode that resets its SVSF memory after a miss
        zs, Ss = self.mode_measurements(s_pred)
        z_c, S_c = self._combine_measurements(zs, Ss, s_pred.mu)
        zero = np.zeros(meas.ndim)
        nus = np.array([meas.residual(nu + meas.residual(z_c, z), zero) for z in zs])  # (r, M, m): z_j - z_i
        if R is not None:  # per-detection S_ij = S_i - R + R_j (thesis §4.1 S = H P H^T + R)
            Ss, S_c = pair_covariances(Ss, R, meas.R), pair_covariances(S_c[None], R, meas.R)[0]
        log_ni = log_gaussian(nus, Ss)  # (r, M): log N_i(z_j), the modes' predicted densities
        log_nc = log_gaussian(nu[None], S_c[None])[0]  # (M,): log N_c(z_j), the density association used
        a = np.concatenate([np.zeros((len(zs), 1)), log_ni - log_nc[None, :]], axis=1)
        b = np.concatenate([[beta0], beta])[None, :]
        log_lam = logsumexp(a, axis=1, b=b)  # (2.103) up to the mode-independent factor lambda D
        with np.errstate(divide="ignore"):
            log_post = log_lam + np.log(s_pred.mu)
        mu = np.exp(log_post - logsumexp(log_post))  # (2.104) mu_i = Lambda_i c_i / sum_l Lambda_l c_l
        kw = {} if R is None else {"R": R}
        modes = tuple(f.update(m, nus[i], beta, beta0, **kw) for i, (f, m) in enumerate(zip(self.filters, s_pred.modes)))
        return self._state(modes, mu)

    def output(self, s: IMMState) -> tuple[np.ndarray, np.ndarray]:
        """Combined estimate (1.17)-(1.18) in the largest mode's layout: (n,), (n, n)."""
        return s.x, s.P

    @property
    def layered(self) -> bool:
        """False if a mode's layer is always None (its `layered` False): `layer` is then None for every state."""
        return all(getattr(f, "layered", True) for f in self.filters)

    def layer(self, s_pred: IMMState) -> np.ndarray | None:
        """c-weighted mean of the modes' boundary layers (m,) if every mode has one, else None ([D])."""
        layers = [f.layer(m) for f, m in zip(self.filters, s_pred.modes)]
        if any(lay is None for lay in layers):
            return None
        return s_pred.mu @ np.array(layers, dtype=np.float64)

    def layers_many(self, preds: list[IMMState], m: int) -> np.ndarray:
        """`layer` of T predicted states at once: (T, m), NaN rows where a mode has none. Each mode's layers by its
        filter's batched form (filters.base.batch_layers), combined as mu (1, r) @ layers (r, m) per track (the
        per-track product, bit for bit)."""
        if not self._stackable(preds):
            return np.array([np.full(m, np.nan) if (lay := self.layer(s)) is None else lay for s in preds],
                            dtype=np.float64).reshape(len(preds), m)
        L = np.stack([batch_layers(f, ms, m) for f, ms in zip(self.filters, self._mode_lists(preds))], axis=1)
        none = np.isnan(L).all(axis=2).any(axis=1)  # a mode without a layer: None
        out = np.matmul(self._mus(preds)[:, None, :], L)[:, 0]  # c-weighted mean ([D])
        out[none] = np.nan
        return out

    # -------------------------------------------------------------------- batched forms
    # The same cycle over T tracks at once (used by the tracker through filters.base.batch_*): the mixing,
    # moment matching, mode likelihoods and mode probabilities vectorised over tracks, each mode's predict
    # and update by its filter's own batched form. The per-track methods above are the reference:
    # tests/test_trackers_imm.py checks every field equal to 1e-12.
    def predict_many(self, states: list[IMMState], dt: float) -> list[IMMState]:
        """`predict` of T tracks: T IMMStates -> T IMMStates; ValueError for dt < 0 or non-finite (also at T = 0)."""
        dt = float(dt)
        if not math.isfinite(dt) or dt < 0:
            raise ValueError(f"predict needs a finite dt >= 0, got {dt}")
        if not states:
            return []
        if not self._stackable(states):
            return [self.predict(s, dt) for s in states]  # unusual states: the per-track reference
        mu = self._mus(states)  # (T, r)
        with np.errstate(divide="ignore"):
            log_w = np.log(self.transition)[None] + np.log(mu)[:, :, None]  # (T, r_j, r_i): log p_ji mu_j
        log_c = logsumexp(log_w, axis=1)  # (2.101) c_i = sum_j p_ji mu_j, (T, r)
        modes, arrays = [], []
        for i, (f, (x0, P0, e0, reach)) in enumerate(zip(self.filters, self._mix_many(states, log_w, log_c))):
            if getattr(f, "predicts_arrays", None) is not None and f.predicts_arrays():  # straight from the arrays
                X, P, F = f.predict_arrays(x0, P0, dt)
                Fs = [F] * len(states) if F.ndim == 2 else F
                modes.append(StateRows([frozen_state(xt, Pt, et, Ft, {}) if type(m) is FilterState
                                        else gvbl_state(xt, Pt, et, Ft, {}, m.psi_layer) if type(m) is GVBLState
                                        else derive_frozen(m, x=xt, P=Pt, F=Ft, e_post=et, info={})
                                        for m, xt, Pt, Ft, et in zip(self._mode_lists(states)[i], X, P, Fs, e0)],
                                       X, P, e0))
                arrays.append((X, P, e0))
            elif getattr(f, "predict_rows", None) is not None and f.motion.linear:  # the mode states with these rows
                modes.append(f.predict_rows(self._mode_lists(states)[i], x0, P0, e0, dt))
                arrays.append(stacked(modes[-1]))
            else:  # the mode filter's own batched predict of the mixed states
                modes.append(batch_predict(f, [derive(s.modes[i], x=x0[t], P=P0[t], e_post=e0[t]) if reach[t]
                                               else s.modes[i] for t, s in enumerate(states)], dt))
                arrays.append(stacked(modes[-1]))
        return self._states_many(states, modes, np.exp(log_c - logsumexp(log_c, axis=1)[:, None]), arrays)

    def mode_measurements_many(self, preds: list[IMMState]) -> tuple[np.ndarray, np.ndarray]:
        """`mode_measurements` of T predicted states: z (T, r, m), S (T, r, m, m), each mode by its filter's
        batched `predicted_measurements`."""
        return self._mode_measurements(self._mode_lists(preds))

    def _measured(self, preds: list[IMMState], lists: list, mu: np.ndarray, active: np.ndarray) -> tuple:
        """(zs (A, r, m), Ss (A, r, m, m), z_c (A, m), S_c (A, m, m)) of the active tracks: the rows of what
        `predicted_measurements` computed for these very states (an IMMRows it was given), else computed from
        their mode states lists and mode probabilities mu (A, r). Every row is computed on its own, so the rows of
        the whole batch are the subset's."""
        kept = getattr(preds, "measured", None) if type(preds) is IMMRows else None
        if kept is not None and len(kept[0]) == len(preds) and all(a is b for a, b in zip(kept[0], preds)):
            return tuple(a[active] for a in kept[1:])
        zs, Ss = self._mode_measurements(lists)
        return (zs, Ss) + self._combine_many(zs, Ss, mu)

    def _mode_measurements(self, lists: list) -> tuple[np.ndarray, np.ndarray]:
        """`mode_measurements_many` of the mode states lists[i] (T each) of every mode i."""
        zS = [batch_predicted_measurements(f, ms) for f, ms in zip(self.filters, lists)]
        return np.stack([z for z, _ in zS], axis=1), np.stack([S for _, S in zS], axis=1)

    def predicted_measurements(self, preds: list[IMMState]) -> tuple[np.ndarray, np.ndarray]:
        """`predicted_measurement` of T predicted states: z_c (T, m), S_c (T, m, m)."""
        m = self.measurement.ndim
        if not preds:
            return np.zeros((0, m)), np.zeros((0, m, m))
        zs, Ss = self.mode_measurements_many(preds)
        z_c, S_c = self._combine_many(zs, Ss, self._mus(preds))
        if type(preds) is IMMRows:  # kept for the update of the same states (`_measured`)
            preds.measured = (tuple(preds), zs, Ss, z_c, S_c)
        return z_c, S_c

    def update_many(self, preds: list[IMMState], nu: np.ndarray, W: np.ndarray, w0: np.ndarray,
                    R: np.ndarray | None = None, log_lik: np.ndarray | None = None) -> list[IMMState]:
        """`update` of T tracks: nu (T, M, m) innovations relative to each track's z_c, W (T, M) weights (0 = not
        used), w0 (T,) miss weights, R (M, m, m) the detections' own covariances or None, log_lik (T, M) log N_c(z_j)
        of every pair as association computed it (trackers.gating; the tracker passes it) or None (computed here). A
        track with no weight > 0 or w0 = 1 gets each mode's own miss handling
        (`_missed_many`), as in `update`. Bad input (non-finite used innovations or weights, rows not summing to 1)
        goes to the per-track loop, which raises the reference's ValueError."""
        T, m = len(preds), self.measurement.ndim
        W, w0 = np.asarray(W, dtype=np.float64), np.asarray(w0, dtype=np.float64)
        nu = np.asarray(nu, dtype=np.float64)
        if nu.shape[:1] + nu.shape[2:] != (T, m) or W.shape != nu.shape[:2] or w0.shape != (T,) \
                or not self._stackable(preds):
            return ModelFilter.update_many(self, preds, nu, W, w0, R)
        use = W > 0.0
        nu_u, W_u = np.where(use[..., None], nu, 0.0), np.where(use, W, 0.0)  # what each per-track update is given
        ok = (np.isfinite(nu_u).all(axis=(1, 2)) & np.isfinite(W_u).all(axis=1) & np.isfinite(w0) & (w0 >= 0.0)
              & (w0 <= 1.0) & (np.abs(w0 + W_u.sum(axis=1) - 1.0) <= 1e-9))
        if not ok.all():
            return ModelFilter.update_many(self, preds, nu, W, w0, R)  # raises as the per-track check_weights
        updated = (w0 < 1.0) & use.any(axis=1)
        active = np.flatnonzero(updated)
        out = list(preds)
        for t, s in self._missed_many(preds, np.flatnonzero(~updated), nu_u, W_u, w0).items():
            out[t] = s
        if active.size == 0:
            return out
        ps = [preds[t] for t in active]
        lists = [take_rows(ms, active) for ms in self._mode_lists(preds)]  # per mode the active tracks' mode states
        nua, Wa, b0 = nu_u[active], W_u[active], w0[active]
        mu_c = self._mus(preds)[active]
        zs, Ss, z_c, S_c = self._measured(preds, lists, mu_c, active)
        meas = self.measurement
        nus = meas.residual(nua[:, None] + meas.residual(z_c[:, None], zs)[:, :, None], np.zeros(m))  # z_j - z_i
        if R is not None:  # per-detection S_ij = S_i - R + R_j (thesis §4.1 S = H P H^T + R)
            A, r = Ss.shape[:2]
            Ss = pair_covariances(Ss.reshape(A * r, m, m), R, meas.R).reshape(A, r, len(R), m, m)
            S_c = pair_covariances(S_c, R, meas.R)
        known = log_lik is not None and np.shape(log_lik) == (T, nu.shape[1])
        mu = self._mode_probabilities_many(nus, Ss, nua, S_c, Wa, b0, mu_c,
                                           np.where(Wa > 0.0, np.asarray(log_lik)[active], 0.0) if known else None)
        modes = [batch_update(f, ms, nus[:, i], Wa, b0, R) for i, (f, ms) in enumerate(zip(self.filters, lists))]
        for t, s in zip(active, self._states_many(ps, modes, mu)):
            out[t] = s
        return out

    def shift_many(self, states: list[IMMState], dkin: np.ndarray, spread: bool = False) -> list[IMMState]:
        """Road-map input (trackers.road): each mode's own `shift_many` (a mode with a nonlinear motion model, the
        CT model, models the turn itself and is unchanged), the combined output recomputed, mu kept. ``spread`` is
        not passed on: a linear mode is the hypothesis "the car follows its lane" and takes the input as exact, the
        turn-rate mode is the alternative (with the spread, imm-pda-kf relabelled a u_turn car, seed 2)."""
        return self._per_mode(states, lambda f, ms: f.shift_many(ms, dkin) if hasattr(f, "shift_many") else ms)

    def pseudo_update_many(self, states: list[IMMState], h: np.ndarray, y: np.ndarray,
                           r: np.ndarray) -> list[IMMState]:
        """Lane keeping (trackers.road): every mode's scalar pseudo-measurement update with h (T, 2), y (T,) taken
        relative to the combined estimate's offset and shifted to each mode's own, r (T,); mu kept [D]."""
        pos = list(self.motion.position[:2])

        def upd(f, ms):
            if not hasattr(f, "pseudo_update_many"):
                return ms
            mpos = list(f.motion.position[:2])
            y_i = y - np.einsum("tk,tk->t", h, np.array([m.x[mpos] for m in ms]) - np.array([s.x[pos] for s in states]))
            return f.pseudo_update_many(ms, h, y_i, r)
        return self._per_mode(states, upd)

    def _per_mode(self, states: list[IMMState], fn) -> list[IMMState]:
        if not states:
            return []
        modes = [fn(f, ms) for f, ms in zip(self.filters, self._mode_lists(states))]
        return self._states_many(states, modes, self._mus(states))

    def _missed_many(self, preds: list[IMMState], idle: np.ndarray, nu: np.ndarray, W: np.ndarray,
                     w0: np.ndarray) -> dict[int, IMMState]:
        """The tracks `idle` (A,) (no weight > 0, or w0 = 1) after a scan without update, as `update` makes them:
        every Lambda_i is equal, so mu stays c, and each mode filter's batched update is given the track's rows
        of nu (T, M, m), W (T, M), w0 (T,), i.e. runs its own miss handling (an SVSF-family mode with
        memory_after_miss = "reset" zeroes its memory). Returns {track: new state} for the tracks a mode changed;
        the others keep their predictions (the same objects)."""
        if idle.size == 0:
            return {}
        ps = [preds[t] for t in idle]
        modes = [batch_update(f, take_rows(ms, idle), nu[idle], W[idle], w0[idle])
                 for f, ms in zip(self.filters, self._mode_lists(preds))]  # (4.16) with beta0 = 1 per mode, its memory rule [D]
        changed = [j for j, s in enumerate(ps) if any(ms[j] is not m for ms, m in zip(modes, s.modes))]
        if not changed:
            return {}
        like = [ps[j] for j in changed]
        new = self._states_many(like, [[ms[j] for j in changed] for ms in modes], np.array([s.mu for s in like]))
        return {int(idle[j]): s for j, s in zip(changed, new)}

    # -------------------------------------------------------------------- internals
    def _stackable(self, states: list[FilterState]) -> bool:
        """True if T states can be stacked: IMMStates of r modes, mode i of one size in every track, one memory
        size (else the batched forms use the per-track reference)."""
        r = len(self.filters)
        if type(states) is IMMRows:  # made by _states_many from stacked modes: stackable
            return True
        if not all(isinstance(s, IMMState) and len(s.modes) == r for s in states):
            return False
        if any(len({s.modes[i].x.size for s in states}) > 1 for i in range(r)):
            return False
        return len({s.modes[i].e_post.shape for i in range(r) for s in states}) <= 1

    def _mix_many(self, states: list[IMMState], log_w: np.ndarray, log_c: np.ndarray) -> list[tuple]:
        """Mixed initial conditions (2.101)-(2.102) of T tracks: per mode i (x0 (T, n_i), P0 (T, n_i, n_i), e0 (T, m),
        reach (T,) bool), read-only; a mode unreachable this scan (reach False) keeps its own state in its rows.
        log_w (T, r, r) = log p_ji mu_j, log_c (T, r) = log c_i."""
        r = len(self.filters)
        X, P, E = zip(*(stacked(ms) for ms in self._mode_lists(states)))
        Es = np.stack(E, axis=1)  # (T, r, m) mode memories
        out = []
        for i, f in enumerate(self.filters):
            reach = np.isfinite(log_c[:, i])  # mode unreachable this scan: nothing to mix into it
            w = np.exp(log_w[:, :, i] - np.where(reach, log_c[:, i], 0.0)[:, None])  # (2.101) mu_{j|i}
            w = np.where(reach[:, None], w, 0.0)
            xs, Ps = zip(*(layout_many(X[j], P[j], f.motion) for j in range(r)))
            x0, P0 = moments_many(np.stack(xs, axis=1), np.stack(Ps, axis=1), w)  # (2.102) mixed initial condition
            e0 = np.einsum("tj,tjm->tm", w, Es)  # §5 [D] mixed memories
            if not reach.all():
                x0 = np.where(reach[:, None], x0, X[i])
                P0 = np.where(reach[:, None, None], P0, P[i])
                e0 = np.where(reach[:, None], e0, E[i])
            freeze(x0, P0, e0)
            out.append((x0, P0, e0, reach))
        return out

    def _combine_many(self, zs: np.ndarray, Ss: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """`_combine_measurements` of T tracks: zs (T, r, m), Ss (T, r, m, m), w (T, r) -> (T, m), (T, m, m)."""
        meas = self.measurement
        z0 = zs[:, 0]
        z_c = z0 + np.einsum("ti,tim->tm", w, meas.residual(zs, z0[:, None, :]))  # moment matching; wraps bearings
        d = meas.residual(zs, z_c[:, None, :])
        S_c = np.einsum("ti,tiab->tab", w, Ss) + np.swapaxes(d * w[:, :, None], 1, 2) @ d  # (1.18)-form spread
        return z_c, 0.5 * (S_c + np.swapaxes(S_c, 1, 2))

    def _mode_probabilities_many(self, nus: np.ndarray, Ss: np.ndarray, nu: np.ndarray, S_c: np.ndarray,
                                 W: np.ndarray, w0: np.ndarray, mu: np.ndarray,
                                 log_nc: np.ndarray | None = None) -> np.ndarray:
        """Updated mode probabilities (A, r) of A updated tracks: nus (A, r, M, m) = z_j - z_i, Ss (A, r, m, m)
        (or per detection (A, r, M, m, m)), nu (A, M, m) = z_j - z_c, S_c (A, m, m) (or (A, M, m, m)), weights
        W (A, M) (0 = not used) and w0 (A,), predicted mu (A, r); log_nc (A, M): log N_c(z_j) as association computed
        it (the same function of the same nu and S_c, row by row: equal on every used pair; an unused pair's
        term is exp(-inf) = 0 whatever its value), else computed here."""
        A, r, M, m = nus.shape
        log_ni = log_gaussian(nus.reshape(A * r, M, m), Ss.reshape((A * r,) + Ss.shape[2:])).reshape(A, r, M)  # log N_i(z_j)
        if log_nc is None:
            log_nc = log_gaussian(nu, S_c)  # (A, M): log N_c(z_j), the density association used
        a = np.concatenate([np.zeros((A, r, 1)), log_ni - log_nc[:, None, :]], axis=2)
        b = np.concatenate([w0[:, None], W], axis=1)[:, None, :]
        log_lam = logsumexp(a, axis=2, b=b)  # (2.103) up to the mode-independent factor lambda D
        with np.errstate(divide="ignore"):
            log_post = log_lam + np.log(mu)
        return np.exp(log_post - logsumexp(log_post, axis=1)[:, None])  # (2.104) mu_i = Lambda_i c_i / sum_l

    def _states_many(self, like: list[IMMState], modes: list[list[FilterState]], mu: np.ndarray,
                     arrays: list | None = None) -> list[IMMState]:
        """`_state` of T tracks: modes[i][t] the mode-i state of track t, mu (T, r); the combined output
        (1.17)-(1.18) vectorised; `like` (T IMMStates) gives each new state's type. arrays: per mode its states'
        stacked (x, P, e_post) when the caller has them (else stacked here)."""
        mts = list(zip(*modes))  # T tuples of r mode states
        if not _one_memory_shape(modes, arrays):
            return [self._state(mt, mu[t]) for t, mt in enumerate(mts)]
        arrays = arrays or [stacked(ms) for ms in modes]
        xs, Ps, Es = zip(*arrays)
        xs, Ps = zip(*(layout_many(x, P, self.motion) for x, P in zip(xs, Ps)))
        x, P = moments_many(np.stack(xs, axis=1), np.stack(Ps, axis=1), mu)  # (1.17)-(1.18) output combination
        check_covariance(P, "IMM combined covariance P")
        e = np.einsum("tj,tjm->tm", mu, np.stack(Es, axis=1))
        mu, mu_info = np.array(mu, dtype=np.float64), np.array(mu, dtype=np.float64)  # the states' and info's copies
        freeze(x, P, e, mu)
        out = []
        told = [(i, _info_keys(name)) for i, (name, ms) in enumerate(zip(self.mode_names, modes))
                if any(m.info for m in ms)]  # the modes with diagnostics, in order, and their keys' names
        for s, mt, xt, Pt, et, mut, mui in zip(like, mts, x, P, e, mu, mu_info):
            info: dict[str, Any] = {"mu": mui}
            for i, keys in told:
                for key, v in mt[i].info.items():
                    info[keys[key]] = v  # "<mode name>.<key>"
            out.append(_imm_state(xt, Pt, et, info, mt, mut) if type(s) is IMMState
                       else derive_frozen(s, x=xt, P=Pt, e_post=et, F=None, info=info, modes=mt, mu=mut))
        return IMMRows(out, mu, [StateRows(ms, *a) for ms, a in zip(modes, arrays)])

    def _mode_lists(self, states: list[IMMState]) -> list:
        """Per mode i the list of the states' mode-i states (the carried StateRows of an IMMRows)."""
        if type(states) is IMMRows:
            return states.mode_lists
        return [[s.modes[i] for s in states] for i in range(len(self.filters))]

    @staticmethod
    def _mus(states: list[IMMState]) -> np.ndarray:
        """Mode probabilities (T, r) of the states (an IMMRows' carried mu)."""
        return states.mu if type(states) is IMMRows else np.array([s.mu for s in states])

    def _combine_measurements(self, zs: np.ndarray, Ss: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        meas = self.measurement
        z_c = zs[0] + w @ meas.residual(zs, zs[0][None, :])  # moment matching; residual wraps bearings
        d = meas.residual(zs, z_c[None, :])
        S_c = np.einsum("i,iab->ab", w, Ss) + (d.T * w) @ d  # (1.18)-form spread in measurement space
        return z_c, symmetrise(S_c)

    def _state(self, modes: tuple[FilterState, ...], mu: np.ndarray) -> IMMState:
        """IMMState with the combined output (1.17)-(1.18) and info {"mu", "<mode>.<key>" for mode infos}."""
        big = self.motion
        xs, Ps = zip(*(to_layout(m, big) for m in modes))
        x, P = moments(np.array(xs), np.array(Ps), mu)  # (1.17)-(1.18) output combination
        check_covariance(P, "IMM combined covariance P")
        if len({m.e_post.shape for m in modes}) == 1:
            e = mu @ np.array([m.e_post for m in modes])
        else:
            e = modes[int(np.argmax(mu))].e_post
        info: dict[str, Any] = {"mu": np.array(mu, dtype=np.float64)}
        for name, m in zip(self.mode_names, modes):
            for key, v in m.info.items():
                info[f"{name}.{key}"] = v
        return IMMState(x=x, P=P, e_post=e, F=None, info=info, modes=modes, mu=mu)


class _PrefixedKeys(dict):
    """key -> "<mode name>.<key>", each name made once (`_info_keys`)."""

    def __init__(self, name: str):
        super().__init__()
        self.name = name

    def __missing__(self, key: str) -> str:
        self[key] = out = f"{self.name}.{key}"
        return out


@functools.lru_cache(maxsize=None)
def _info_keys(mode_name: str) -> _PrefixedKeys:
    """The names of mode `mode_name`'s diagnostics in an IMM state's info, made once per key (T per scan read them)."""
    return _PrefixedKeys(mode_name)


def _one_memory_shape(modes: list, arrays: list | None) -> bool:
    """True if every mode state of modes (r lists) has the same e_post shape; read from the stacked memories of
    `arrays` (per mode (x, P, e_post)) or of a StateRows carrying them, else from the states."""
    shapes = set()
    for i, ms in enumerate(modes):
        E = arrays[i][2] if arrays else (ms.e_post if type(ms) is StateRows else None)
        if E is not None:
            shapes.add(E.shape[1:])
        else:
            shapes.update(m.e_post.shape for m in ms)
    return len(shapes) <= 1


def default_mode_names(filters) -> tuple[str, ...]:
    """Motion-model keys ("cv", "ct"); numbered ("cv0", "cv1") when a key repeats."""
    keys = {cls: k for k, cls in MOTION_MODELS.items()}
    base = [keys.get(type(f.motion), type(f.motion).__name__.lower()) for f in filters]
    return tuple(f"{b}{i}" if base.count(b) > 1 else b for i, b in enumerate(base))


def check_markov(Pi: np.ndarray, mu0: np.ndarray, r: int) -> None:
    """ParamError ("transition" / "mu0") unless Pi is (r, r) row-stochastic and mu0 (r,) a distribution."""
    if Pi.shape != (r, r):
        raise ParamError("transition", f"expected a {r} x {r} matrix (one row and column per mode), "
                         f"got shape {Pi.shape}")
    if not np.isfinite(Pi).all() or (Pi < 0).any():
        raise ParamError("transition", "entries must be finite probabilities >= 0")
    rows = Pi.sum(axis=1)
    bad = np.flatnonzero(np.abs(rows - 1.0) > 1e-9)
    if bad.size:
        raise ParamError("transition", f"row {int(bad[0])} sums to {rows[bad[0]]:.12g}; each row "
                         "p_j. = P{mode j -> any mode} must sum to 1")
    if mu0.shape != (r,):
        raise ParamError("mu0", f"expected {r} mode probabilities, got shape {mu0.shape}")
    if not np.isfinite(mu0).all() or (mu0 < 0).any() or abs(mu0.sum() - 1.0) > 1e-9:
        raise ParamError("mu0", f"must be probabilities >= 0 summing to 1, got {mu0.tolist()}")


# ---------------------------------------------------------------------------------------- parameters
DEFAULT_MODES = ({"kind": "kf", "motion": "cv"}, {"kind": "ekf", "motion": "ct"})


def default_markov(r: int) -> tuple[np.ndarray, np.ndarray]:
    """Reference §5 [D]: p_ii = 0.95 and 0.05 shared off the diagonal; mu0 = 0.9 on mode 0, 0.1 shared
    (r = 2: Pi = [[0.95, 0.05], [0.05, 0.95]], mu0 = [0.9, 0.1]); r = 1: [[1]], [1]."""
    if r == 1:
        return np.ones((1, 1)), np.ones(1)
    Pi = np.full((r, r), 0.05 / (r - 1))
    np.fill_diagonal(Pi, 0.95)
    return Pi, np.array([0.9] + [0.1 / (r - 1)] * (r - 1))


@dataclass(frozen=True)
class IMMParams:
    """IMM parameters (thesis §2.3.4). Mode tables: {"kind": <filter>, ...that filter's parameters}."""

    modes: tuple[dict, ...] = param(DEFAULT_MODES, "mode-matched filters, each a filter table with 'kind' "
                                    "(thesis §2.3: NCV + CT)")
    transition: tuple[tuple[float, ...], ...] = param((), "Markov matrix per scan, row j = P{mode j -> mode i}, "
                                                      "rows sum to 1; () = 0.95 on the diagonal ([D], the thesis gives none)")
    mu0: tuple[float, ...] = param((), "initial mode probabilities; () = [0.9, 0.1] ([D], the thesis gives none)")
    sigma_v: float | None = param(None, "white-acceleration std [m/s^2] for every mode table that has the key "
                                  "and does not set it", check=NON_NEGATIVE)
    sigma_w: float | None = param(None, "measurement noise std [m] for every mode table that has the key "
                                  "and does not set it", check=POSITIVE)
    detection_R: bool | None = param(None, "each detection's own covariance in the gate, likelihood and update "
                                     "(see the kf table) for every mode table that has the key and does not set it")

    def __post_init__(self) -> None:
        r = len(self.modes)
        if r < 1:
            raise ParamError("modes", "needs at least one mode table")
        Pi, mu0 = default_markov(r)
        check_markov(np.array(self.transition, dtype=np.float64) if self.transition else Pi,
                     np.array(self.mu0, dtype=np.float64) if self.mu0 else mu0, r)


def build_imm(p: IMMParams, registry: dict, build_filter) -> IMMFilter:
    """IMMFilter from its parameters, its modes built by the filter registry (``registry`` = ``FILTERS`` and
    ``build_filter`` of trackers.filters, passed in by the registry's entry); ParamError paths relative to the
    IMM table ("modes[1].sigma_v")."""
    filters = []
    for i, table in enumerate(p.modes):
        path = f"modes[{i}]"
        kind = table.get("kind")
        if not isinstance(kind, str):
            raise ParamError(f"{path}.kind", f"missing or not a string ({kind!r}); allowed: "
                             f"{', '.join(sorted(k for k in registry if k != 'imm'))}")
        if kind == "imm":
            raise ParamError(f"{path}.kind", "an IMM mode must be a single-model filter, not 'imm'")
        data = {k: v for k, v in table.items() if k != "kind"}
        if kind in registry:
            keys = {f.name for f in dataclasses.fields(registry[kind].params) if f.init}
            for key in ("sigma_v", "sigma_w", "detection_R"):
                if getattr(p, key) is not None and key in keys:
                    data.setdefault(key, getattr(p, key))  # shared scenario value; a mode's own value wins
        filters.append(build_filter(kind, data, path))
        if filters[-1].measurement != filters[0].measurement:
            raise ParamError(path, f"measurement model {filters[-1].measurement} differs from modes[0]'s "
                             f"{filters[0].measurement}; all modes must share one (set sigma_w once)")
    Pi, mu0 = default_markov(len(filters))
    try:
        return IMMFilter(tuple(filters), np.array(p.transition) if p.transition else Pi,
                         np.array(p.mu0) if p.mu0 else mu0)
    except ParamError:
        raise
    except ValueError as err:
        raise ParamError("modes", str(err).splitlines()[0]) from None


CT_KIND = {"kf": "ekf", "svsf": "gvbl-svsf", "gc-svsf": "gvbl-svsf"}
"""Base filters that cannot run the 5-D CT model and the kind used for their CT mode."""


def imm_wrapper(base: str) -> tuple[str, dict[str, Any]]:
    """WRAPPERS["imm"]: an NCV mode of the base filter and a CT mode of the same kind (thesis §2.3.5: a linear
    filter for NCV, its extended form for CT). Three bases cannot run CT: the linear KF (its CT mode is the
    EKF), the standard SVSF, whose gain never corrects the turn rate, and the gc-svsf, whose partitioned gain
    with the 2 x 3 pseudo-inverse Phi12^+ (thesis §2.3.5 leaves the EK-SVSF's form open) pushes position
    errors into the turn rate and diverged on a turning target (velocity errors of 1e7 m/s within 60
    scans). Their CT mode is the gvbl-svsf, which linearises the CT model (EK form) and needs no Phi12^-1
    in its optimal regime (thesis (4.73))."""
    if base == "imm":
        raise ParamError("filter.kind", "the imm wrapper needs a single-model base filter, got 'imm'")
    return "imm", {"modes": ({"kind": base, "motion": "cv"}, {"kind": CT_KIND.get(base, base), "motion": "ct"})}
