"""The associator role: typed parameters, the per-scan input, and the registry of associators."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from roadtrack.trackers.association.an import DISTANCES, all_neighbours, an_distances
from roadtrack.trackers.association.apda import FORMS, LAYER_MODES, apda
from roadtrack.trackers.association.gnn import global_nearest_neighbour
from roadtrack.trackers.association.jpda import DEFAULT_K, DEFAULT_MAX_NODES, FALLBACK_DIAGNOSTIC, METHODS, jpda_fallbacks
from roadtrack.trackers.association.nn import nearest_neighbour
from roadtrack.trackers.association.params import OVERFLOW_MODES, AssociationParams
from roadtrack.trackers.association.pda import pda
from roadtrack.trackers.gating import gate_probability
from roadtrack.trackers.params import NON_NEGATIVE, POSITIVE, PROBABILITY, ParamError, load, param


@dataclass(frozen=True, eq=False)
class AssociationInput:
    """One scan's association problem for T tracks and M measurements of dimension m.

    log_lik (T, M) log N(nu; 0, S); gated (T, M) bool; d2 (T, M) squared Mahalanobis distances;
    nu (T, M, m) innovations; S (T, m, m); pd (T,) per-track detection probability; pg gate
    probability; gate_volume (T,) [m^m]; layers (T, m) boundary-layer half widths of SVSF-family
    filters in measurement space (NaN rows for filters without one); S_pairs (T, M, m, m) the innovation covariance
    of every (track, measurement) pair when measurements carry their own covariances (log_lik and d2 use it;
    S and gate_volume are the tracks' with the filter's fixed R), else None."""

    log_lik: np.ndarray
    gated: np.ndarray
    d2: np.ndarray
    nu: np.ndarray
    S: np.ndarray
    pd: np.ndarray
    pg: float
    gate_volume: np.ndarray
    layers: np.ndarray
    S_pairs: np.ndarray | None = None


@dataclass(frozen=True)
class AssociatorParams:
    """Parameters every associator shares: the gate and the scene assumptions (thesis §4.1-4.4)."""

    gate_alpha: float = param(16.0, "chi-square gate threshold alpha (thesis §4.1: 16, P_G = 0.9997)", check=POSITIVE)
    pd: float = param(0.9, "detection probability P_D (a per-track value from the caller overrides it)",
                      check=PROBABILITY)
    clutter_density: float = param(1e-2, "Poisson clutter density lambda [1/m^2] (thesis §4.6.2: 1e-2)",
                                   check=POSITIVE)
    use_pg: bool = param(False, "JPDA and GNN in the P_D P_G form (thesis §4.4 note) instead of the thesis form")
    pg: float | None = param(None, "gate probability P_G in the PDA (4.10)-(4.13) and APDA (5.54) weights, in JPDA "
                             "and GNN with use_pg, and in the track score (1.35); None: the gate's chi-square mass "
                             "F_chi2_m(gate_alpha) (thesis §4.6.1 prints alpha = 16 with P_G = 0.9997 = "
                             "F_chi2_2(16)); a value: that P_G whatever the gate (e.g. a paper's printed P_G that is "
                             "not its gate's)", check=PROBABILITY)

    def gate_probability(self, m: int) -> float:
        """P_G for m measurement components: `pg` if set, else F_chi2_m(gate_alpha) (trackers.gating)."""
        return gate_probability(self.gate_alpha, m) if self.pg is None else self.pg  # (4.10)-(4.13) P_G

    def problem(self, pg: float, **extra: Any) -> AssociationParams:
        """The plain-function parameter object for gate probability `pg`."""
        return AssociationParams(pd=self.pd, pg=pg, clutter_density=self.clutter_density, use_pg=self.use_pg,
                                 **extra)


@dataclass(frozen=True)
class JPDAParams(AssociatorParams):
    """JPDA (thesis §4.4): exact by EHM (default) or enumeration, or approximate from the k best events."""

    method: str = param("ehm", "exact 'ehm' (hypothesis net), exact 'enumerate' (joint events; the test oracle) "
                        "or approximate 'k_best' (Murty)", choices=METHODS)
    k: int = param(DEFAULT_K, "k_best (and the k_best fallback): joint events kept per cluster", check=POSITIVE,
                   bounds=(1, 10_000))
    max_nodes: int = param(DEFAULT_MAX_NODES, "ehm: budget of edges in one net layer (above it on_overflow)",
                           check=POSITIVE, bounds=(1, 2**24))  # 2^24 edges: about 1 GB of net arrays
    max_events: int = param(50_000, "enumerate: cap on the feasible joint events of one cluster", check=POSITIVE,
                            bounds=(1, 10_000_000))  # 10^7 events x the cluster's measurements, int64
    on_overflow: str = param("k_best", "a cluster over its budget (max_nodes, max_events): that cluster's k best "
                             "events, per-track PDA (with a warning) or an error; fallbacks are counted",
                             choices=OVERFLOW_MODES)


@dataclass(frozen=True)
class ANParams(AssociatorParams):
    """All-neighbours linear-distance weights (seed 001 (22)-(23)); P_D and lambda serve track scoring only."""

    distance: str = param("euclidean", "D_ij of seed 001 (23): Euclidean innovation norm [D], Mahalanobis distance "
                          "or its square", choices=DISTANCES)


@dataclass(frozen=True)
class APDAParams(AssociatorParams):
    """Chattering-augmented PDA (thesis (5.37)-(5.54)). A flat `make_tracker(..., psi_max=...)` keyword goes to
    the filter's psi_max when the filter has one (GVBL-SVSF, whose layer it caps); the associator's is then set
    with `associator={"psi_max": ...}`."""

    form: str = param("consistent", "constants of (5.54): 'consistent' (re-derived a with 1/P_D, normalised "
                      "half-normal) or 'thesis' (as printed)", choices=FORMS)
    psi_max: float = param(2.0, "boundary-layer half width [m] for filters without one (and the saturation of "
                           "layer='saturated'); about 1-2 sigma_w [D] (the ch. 4 value, 20 m, would make APDA equal PDA)", check=NON_NEGATIVE)
    layer: str = param("filter", "'filter': the filter's layer as given; 'saturated': min(layer, psi_max) (§6.5)",
                       choices=LAYER_MODES)


@dataclass(frozen=True)
class AssociatorKind:
    run: Callable[[AssociationInput, Any], tuple]
    params: type
    doc: str


def _plain(fn: Callable) -> Callable[[AssociationInput, AssociatorParams], tuple]:
    def run(inp: AssociationInput, p: AssociatorParams) -> tuple:
        return fn(inp.log_lik, inp.gated, p.problem(inp.pg), inp.pd)
    run.__doc__ = fn.__doc__
    return run


def _jpda(inp: AssociationInput, p: JPDAParams) -> tuple:
    W, w0, fell_back = jpda_fallbacks(inp.log_lik, inp.gated, p.problem(inp.pg, max_events=p.max_events,
                                                                         on_overflow=p.on_overflow),
                                      inp.pd, method=p.method, k=p.k, max_nodes=p.max_nodes)
    return W, w0, {FALLBACK_DIAGNOSTIC: np.where(fell_back, 1.0, np.nan)}


def _an(inp: AssociationInput, p: ANParams) -> tuple:
    return all_neighbours(an_distances(inp.nu, inp.d2, p.distance), inp.gated)


def _apda(inp: AssociationInput, p: APDAParams) -> tuple:
    return apda(inp.nu, inp.S, inp.log_lik, inp.gated, inp.layers, inp.gate_volume, inp.pd, inp.pg,
                p.clutter_density, p.gate_alpha, form=p.form, psi_max=p.psi_max, layer_mode=p.layer,
                S_pairs=inp.S_pairs)


ASSOCIATORS: dict[str, AssociatorKind] = {
    "nn": AssociatorKind(_plain(nearest_neighbour), AssociatorParams,
                         "nearest neighbour: each track its most likely gated measurement"),
    "gnn": AssociatorKind(_plain(global_nearest_neighbour), AssociatorParams,
                          "global nearest neighbour: the most probable joint assignment"),
    "pda": AssociatorKind(_plain(pda), AssociatorParams, "probabilistic data association (thesis §4.2)"),
    "jpda": AssociatorKind(_jpda, JPDAParams, "joint PDA per cluster (thesis §4.4): exact by EHM, or k best events"),
    "an": AssociatorKind(_an, ANParams, "all neighbours, weights linear in distance (seed 001 (22)-(23))"),
    "apda": AssociatorKind(_apda, APDAParams, "PDA augmented with the SVSF chattering (thesis (5.37)-(5.54))"),
}


def build_associator(kind: str, data: dict, path: str = "associator") -> tuple[AssociatorKind, Any]:
    """(AssociatorKind, its validated parameters) from a parameter table; ParamError on bad input."""
    if kind not in ASSOCIATORS:
        raise ParamError(f"{path}.kind", f"unknown associator {kind!r}; allowed: {', '.join(sorted(ASSOCIATORS))}")
    ak = ASSOCIATORS[kind]
    return ak, load(ak.params, data, path)
