"""Shared by the batched-versus-per-track filter tests: every field of a filter state by dotted name."""
from __future__ import annotations


def state_fields(s, prefix: str = "") -> dict:
    """Every field of a state by dotted name: arrays, scalars, each info entry, each IMM mode state's fields."""
    out = {}
    for k, v in vars(s).items():
        if k == "info":
            out.update({f"{prefix}info.{key}": val for key, val in v.items()})
        elif k == "modes":
            for i, m in enumerate(v):
                out.update(state_fields(m, f"{prefix}modes[{i}]."))
        else:
            out[prefix + k] = v
    return out
