"""Errors and warnings raised by `trackers`.

Every message is one line and names the offending quantity, so a failure deep in a run reads as
"what went wrong" rather than as a numpy traceback.
"""


class FilterError(ValueError):
    """A filter met a covariance that is non-finite or not positive definite."""


class JPDAOverflowError(ValueError):
    """A JPDA cluster has more feasible joint events than `AssociationParams.max_events`."""


class JPDAOverflowWarning(RuntimeWarning):
    """A JPDA cluster was too large and was associated with per-track PDA instead (documented fallback)."""
