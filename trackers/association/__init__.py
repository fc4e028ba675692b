"""Data association: (T, M) log-likelihoods and gate flags in, weights (T, M) and miss weights (T,) out.

Registry: name -> fn(log_lik, gated, p: AssociationParams) -> (W, w0). Adding an associator = one
module, one line here; the registry contract tests then run it."""

from trackers.association.gnn import global_nearest_neighbour
from trackers.association.jpda import jpda
from trackers.association.nn import nearest_neighbour
from trackers.association.params import AssociationParams
from trackers.association.pda import pda

ASSOCIATORS = {
    "nn": nearest_neighbour,
    "gnn": global_nearest_neighbour,
    "pda": pda,
    "jpda": jpda,
}

__all__ = ["ASSOCIATORS", "AssociationParams", "global_nearest_neighbour", "jpda", "nearest_neighbour", "pda"]
