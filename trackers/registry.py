"""Tracker names: "<associator>-<filter>", optionally prefixed by a filter wrapper: "<wrapper>-<associator>-<filter>".

Associators come from `trackers.association.ASSOCIATORS`, filters from `trackers.filters.FILTERS`,
wrappers (e.g. a future "imm" that builds an IMM filter around a base filter) from `WRAPPERS`.
Names may contain hyphens ("jpda-gvbl-svsf"): a name is split by matching registered names, not by '-'.

Parameters of `make_tracker(name, **params)`: every `TrackerParams` field, plus every keyword parameter
of the filter constructor (and of the wrapper, after its first positional argument, the base filter).
A filter parameter that is also a TrackerParams field (sigma_v, sigma_w) takes the TrackerParams value.
"""

from __future__ import annotations

import inspect
from dataclasses import fields
from typing import Any, Callable

from trackers.association import ASSOCIATORS
from trackers.filters import FILTERS
from trackers.tracker import Tracker, TrackerParams

WRAPPERS: dict[str, Callable[..., Any]] = {}  # "imm": fn(base_filter, **params) -> filter (later)


def _keyword_params(fn: Callable[..., Any], skip_first: bool = False) -> dict[str, inspect.Parameter]:
    ps = [p for p in inspect.signature(fn).parameters.values()
          if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)]
    return {p.name: p for p in (ps[1:] if skip_first else ps)}


def parse_tracker_name(name: str) -> tuple[str | None, str, str]:
    """Split a tracker name into (wrapper or None, associator, filter); ValueError listing valid names."""
    matches = []
    for w in [None, *WRAPPERS]:
        rest = name if w is None else (name[len(w) + 1:] if name.startswith(w + "-") else None)
        if rest is None:
            continue
        for a in ASSOCIATORS:
            if rest.startswith(a + "-") and rest[len(a) + 1:] in FILTERS:
                matches.append((w, a, rest[len(a) + 1:]))
    if len(matches) != 1:
        what = "unknown" if not matches else "ambiguous"
        raise ValueError(f"{what} tracker name {name!r}: use '[<wrapper>-]<associator>-<filter>' with associators "
                         f"{sorted(ASSOCIATORS)}, filters {sorted(FILTERS)}, wrappers {sorted(WRAPPERS)}")
    return matches[0]


def available_trackers() -> list[str]:
    """Every valid tracker name, sorted."""
    base = [f"{a}-{f}" for a in ASSOCIATORS for f in FILTERS]
    return sorted(base + [f"{w}-{b}" for w in WRAPPERS for b in base])


def make_tracker(name: str, **params: Any) -> Tracker:
    """Build a Tracker from its registered name, e.g. make_tracker("jpda-kf", sigma_v=1.5)."""
    wrapper, assoc, filt = parse_tracker_name(name)
    tracker_keys = {f.name for f in fields(TrackerParams)}
    filter_ps = _keyword_params(FILTERS[filt])
    wrapper_ps = _keyword_params(WRAPPERS[wrapper], skip_first=True) if wrapper else {}
    valid = tracker_keys | set(filter_ps) | set(wrapper_ps)
    unknown = sorted(set(params) - valid)
    if unknown:
        raise ValueError(f"unknown parameter(s) {unknown} for tracker {name!r}; valid parameters: {sorted(valid)}")
    tp = TrackerParams(**{k: v for k, v in params.items() if k in tracker_keys})

    def kwargs(ps: dict[str, inspect.Parameter], owner: str) -> dict[str, Any]:
        kw = {k: (getattr(tp, k) if k in tracker_keys else params[k])
              for k in ps if k in tracker_keys or k in params}
        missing = sorted(k for k, p in ps.items() if k not in kw and p.default is inspect.Parameter.empty)
        if missing:
            raise ValueError(f"{owner} of tracker {name!r} needs parameter(s) {missing}")
        return kw

    flt = FILTERS[filt](**kwargs(filter_ps, f"filter {filt!r}"))
    if wrapper:
        flt = WRAPPERS[wrapper](flt, **kwargs(wrapper_ps, f"wrapper {wrapper!r}"))
    return Tracker(filter=flt, associate=ASSOCIATORS[assoc], params=tp)
