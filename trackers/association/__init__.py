"""Data association: (T, M) log-likelihoods and gate flags in, weights (T, M) and miss weights (T,) out.

Two layers:
* plain functions on arrays, testable with hand-made arrays: `fn(log_lik, gated, p: AssociationParams,
  pd=None) -> (W, w0)` (nn, gnn, pda, jpda), `all_neighbours(D, gated)` (an), `apda(nu, S, ...)` (apda);
* the role registry ASSOCIATORS: name -> AssociatorKind(run, params dataclass, doc), where
  `run(inp: AssociationInput, params) -> (W, w0)` or `(W, w0, info)`; `info` maps names to per-track
  (T,) arrays reported as diagnostics. The tracker builds the AssociationInput once per scan (it also
  carries innovations, S, per-track P_D and the filters' boundary layers for APDA).
The associators' log-sum-exp is `logsum.logsumexp` (scipy's, bit for bit, without its dispatch cost).

Adding an associator = one module, one line here; the registry contract tests then run it."""

from roadtrack.trackers.association.an import all_neighbours
from roadtrack.trackers.association.apda import apda
from roadtrack.trackers.association.gnn import global_nearest_neighbour
from roadtrack.trackers.association.jpda import jpda
from roadtrack.trackers.association.nn import nearest_neighbour
from roadtrack.trackers.association.params import AssociationParams
from roadtrack.trackers.association.pda import pda
from roadtrack.trackers.association.roles import (ASSOCIATORS, AssociationInput, AssociatorKind, AssociatorParams, ANParams,
                                        APDAParams, JPDAParams, build_associator)

__all__ = ["ANParams", "APDAParams", "ASSOCIATORS", "AssociationInput", "AssociationParams", "AssociatorKind",
           "AssociatorParams", "JPDAParams", "all_neighbours", "apda", "build_associator", "global_nearest_neighbour",
           "jpda", "nearest_neighbour", "pda"]
