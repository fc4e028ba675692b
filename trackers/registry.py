"""Tracker names are presets: "<associator>-<filter>", optionally "<wrapper>-<associator>-<filter>".

A name fills three parameter tables, which the caller may override key by key:
    filter      {kind from the name, ...}        e.g. sigma_v, sigma_w, gamma, psi_max (trackers.filters)
    associator  {kind from the name, ...}        e.g. gate_alpha, pd, clutter_density (trackers.association)
    management  {kind: "score" | "m_of_n", ...}  initiation, confirmation, deletion (trackers.management)
A wrapper (e.g. "imm") turns the filter table into its own (an IMM whose modes are built from the base
filter). Names may contain hyphens ("jpda-gvbl-svsf"): a name is split by matching registered names.

`make_tracker(name, filter={...}, associator={...}, management={...})` takes the tables; flat keyword
parameters (`make_tracker("jpda-kf", sigma_v=1.5, clutter_density=1e-3)`) are routed to the one table
that has the key (filter first, then associator, then management).
"""

from __future__ import annotations

import dataclasses
from typing import Any, Callable

from roadtrack.trackers.association.roles import ASSOCIATORS, build_associator
from roadtrack.trackers.filters import FILTERS, build_filter
from roadtrack.trackers.filters.imm import imm_wrapper
from roadtrack.trackers.management import MANAGERS, ManagementParams, build_management
from roadtrack.trackers.params import ParamError, load
from roadtrack.trackers.tracker import Tracker

# wrapper name -> fn(base filter kind) -> (filter kind, default filter table); see trackers.filters.imm
WRAPPERS: dict[str, Callable[[str], tuple[str, dict[str, Any]]]] = {"imm": imm_wrapper}


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
                         f"{sorted(ASSOCIATORS)}, filters {sorted(f for f in FILTERS if f not in WRAPPERS)}, "
                         f"wrappers {sorted(WRAPPERS)}")
    return matches[0]


def available_trackers() -> list[str]:
    """Every valid tracker name, sorted."""
    base = [f"{a}-{f}" for a in ASSOCIATORS for f in FILTERS if f not in WRAPPERS]
    return sorted(base + [f"{w}-{b}" for w in WRAPPERS for b in base])


PAPER_TRACKERS = ("nn-kf", "gnn-kf", "pda-kf", "an-kf", "jpda-kf", "pda-svsf", "jpda-svsf", "jpda-gvbl-svsf",
                  "imm-pda-kf", "imm-pda-svsf", "imm-jpda-gvbl-svsf", "apda-svsf", "apda-gvbl-svsf")
"""The trackers of the papers (thesis §4.5 table, seed 001's AN), a fixed list: `testbed trackers` lists these
first; reproductions and tests name their own lists, so an installed plug-in never changes what they run."""


def named_trackers(all_combinations: bool = False) -> list[str]:
    """The papers' named trackers (or every combination, plug-ins included)."""
    return available_trackers() if all_combinations else list(PAPER_TRACKERS)


def plugin_trackers() -> list[str]:
    """The combinations of the installed plug-in filters with every associator and of the plug-in associators
    with every filter (no wrapper), sorted (trackers.plugins)."""
    from roadtrack.trackers.plugins import PLUGINS

    filters = [f for f in FILTERS if f not in WRAPPERS]
    names = {f"{a}-{f}" for a in ASSOCIATORS for f in PLUGINS["filter"]}
    names |= {f"{a}-{f}" for a in PLUGINS["associator"] for f in filters}
    return sorted(names)


def describe_tracker(name: str) -> str:
    """One line: what the associator and the filter (and wrapper) of `name` are."""
    wrapper, assoc, filt = parse_tracker_name(name)
    if wrapper is None:
        return f"{ASSOCIATORS[assoc].doc}; {FILTERS[filt].doc}"
    modes = ", ".join(f"{m.get('kind')} {m.get('motion', 'cv')}" for m in preset(name)["filter"].get("modes", ()))
    return f"{ASSOCIATORS[assoc].doc}; {wrapper.upper()} (thesis §2.3.4) of {modes} modes; base: {FILTERS[filt].doc}"


def preset(name: str) -> dict[str, dict[str, Any]]:
    """The parameter tables a tracker name stands for (kinds and the wrapper's defaults)."""
    wrapper, assoc, filt = parse_tracker_name(name)
    ftable: dict[str, Any] = {"kind": filt}
    if wrapper is not None:
        kind, table = WRAPPERS[wrapper](filt)
        ftable = {"kind": kind, **table}
    return {"filter": ftable, "associator": {"kind": assoc}, "management": {"kind": "score"}}


def _field_names(cls: type) -> set[str]:
    return {f.name for f in dataclasses.fields(cls) if f.init}


def _route(flat: dict[str, Any], tables: dict[str, dict[str, Any]], name: str) -> None:
    fclass = FILTERS[tables["filter"]["kind"]].params
    aclass = ASSOCIATORS[tables["associator"]["kind"]].params
    for key, value in flat.items():
        for role, cls in (("filter", fclass), ("associator", aclass), ("management", ManagementParams)):
            if key in _field_names(cls):
                tables[role][key] = value
                break
        else:
            valid = sorted(_field_names(fclass) | _field_names(aclass) | _field_names(ManagementParams))
            raise ParamError(key, f"unknown parameter for tracker {name!r}; valid parameters: {valid}")


def known_keys(name: str) -> dict[str, set[str]]:
    """The parameter names each table ("filter", "associator", "management") of tracker `name` accepts."""
    tables = preset(name)  # per-kind sub-tables (filter.svsf, associator.apda, ...) are accepted by every tracker
    return {"filter": _field_names(FILTERS[tables["filter"]["kind"]].params) | {"kind"} | set(FILTERS),
            "associator": _field_names(ASSOCIATORS[tables["associator"]["kind"]].params) | {"kind"} | set(ASSOCIATORS),
            "management": _field_names(ManagementParams) | {"kind"}}


def _kind_tables(role: str, given: dict[str, Any]) -> tuple[dict[str, Any], dict[str, dict[str, Any]]]:
    """Split a role table into its plain keys and its per-kind sub-tables (e.g. filter.svsf = {psi = 0.2}): a
    sub-table named after a registered filter (associator) applies only when that kind is in use."""
    kinds = FILTERS if role == "filter" else ASSOCIATORS if role == "associator" else {}
    plain = {k: v for k, v in given.items() if not (k in kinds and isinstance(v, dict))}
    return plain, {k: v for k, v in given.items() if k in kinds and isinstance(v, dict)}


def _apply_kind_tables(role: str, table: dict[str, Any], subs: dict[str, dict[str, Any]]) -> None:
    """Merge the sub-table of the table's kind (and, for an IMM, of each mode's kind into that mode); check the
    other sub-tables strictly against their own kind so a typo is still an error."""
    kinds = FILTERS if role == "filter" else ASSOCIATORS
    for kind, sub in subs.items():
        load(kinds[kind].params, sub, f"{role}.{kind}")  # errors name the sub-table's own dotted key
    if table["kind"] in subs:
        table.update(subs[table["kind"]])  # the kind's own sub-table wins over the plain keys
    if role == "filter" and "modes" in table:
        table["modes"] = tuple({**subs.get(m.get("kind", ""), {}), **m} if isinstance(m, dict) else m
                               for m in table["modes"])


def make_tracker(name: str, *, filter: dict | None = None, associator: dict | None = None,
                 management: dict | None = None, lenient: bool = False, **flat: Any) -> Tracker:
    """Build a Tracker from its name and optional parameter tables (see module docstring). Raises ParamError
    (a ValueError) naming the dotted key, e.g. "filter.sigma_v: expected a finite number, got 'x'".
    A filter or associator table may hold sub-tables named after a kind (`filter={"svsf": {"psi": 0.2}}`):
    they apply only when that kind is in use (also inside an IMM's modes), so one scenario can carry tuned
    parameters for several trackers. lenient: drop plain keys this tracker does not have (tables written
    for another tracker, e.g. a scenario's tables when `--tracker` picks a different one)."""
    tables = preset(name)
    keys = known_keys(name) if lenient else None
    subs: dict[str, dict[str, dict[str, Any]]] = {}
    for role, given in (("filter", filter), ("associator", associator), ("management", management)):
        given, subs[role] = _kind_tables(role, dict(given or {}))
        if given and keys is not None:
            given = {k: v for k, v in given.items() if k in keys[role] and (k != "kind" or role == "management")}
        if given:
            if role != "management" and "kind" in given and given["kind"] != tables[role]["kind"]:
                raise ParamError(f"{role}.kind", f"is set by the tracker name {name!r} "
                                 f"({tables[role]['kind']!r}); choose another name instead")
            tables[role].update(given)
    _route(flat, tables, name)
    for role in ("filter", "associator"):
        _apply_kind_tables(role, tables[role], subs[role])
    ft, at, mt = (dict(tables[r]) for r in ("filter", "associator", "management"))
    flt = build_filter(ft.pop("kind"), ft, "filter")
    kind, ap = build_associator(at.pop("kind"), at, "associator")
    manager = mt.pop("kind", "score")
    mp = build_management(manager, mt, "management")
    return Tracker(filter=flt, associator=kind, association=ap, management=mp, manager=manager, name=name)


def parameter_tables() -> list[tuple[str, str, type]]:
    """(table, kind, parameter dataclass) of every filter, associator and manager, for `testbed keys`."""
    rows = [("filter", k, fk.params) for k, fk in sorted(FILTERS.items())]
    rows += [("associator", k, ak.params) for k, ak in sorted(ASSOCIATORS.items())]
    rows.append(("management", " or ".join(MANAGERS), ManagementParams))
    return rows
