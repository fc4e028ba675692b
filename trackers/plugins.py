"""Filters and associators from installed packages (plug-ins), found by their entry points.

A package adds a filter by declaring, in its ``pyproject.toml``::

    [project.entry-points."roadtrack.filters"]
    ab = "my_package.ab:AB"            # a roadtrack.trackers.filters.FilterKind (or a function returning one)

    [project.entry-points."roadtrack.associators"]
    mine = "my_package.assoc:MINE"     # a roadtrack.trackers.association.AssociatorKind (or a function returning one)

A script or notebook adds one in its own process with :func:`register_filter` and :func:`register_associator`.
Once it is installed (``pip install my-package``) the entry point's name is a registered kind: ``jpda-ab``,
``imm-pda-ab``, ``mine-kf`` ... are tracker names, listed by ``testbed trackers`` and ``testbed keys``, and its
parameters are loaded and bounded like the built-ins' (trackers.params). A plug-in that cannot be loaded, is
not of the right type, has an invalid name or takes a built-in's name is skipped with one
:class:`PluginWarning` line naming it: an installed package never breaks the project nor replaces a built-in.
"""

from __future__ import annotations

import dataclasses
import re
import warnings
from importlib import metadata
from typing import Any

GROUPS = {"filter": "roadtrack.filters", "associator": "roadtrack.associators"}
"""Role -> entry-point group."""
TRACKER_GROUP = "roadtrack.trackers"
"""Entry-point group of whole trackers (objects with ``step(frame)``; the testbed's tracker protocol)."""
NAME = re.compile(r"[a-z][a-z0-9]*(?:-[a-z0-9]+)*\Z")
"""A plug-in's name: lower-case letters and digits, words joined by single hyphens (like the built-ins)."""


class PluginWarning(UserWarning):
    """An installed plug-in was skipped (one line: the entry point, its package and why)."""


def entry_points(group: str) -> list[metadata.EntryPoint]:
    """The installed entry points of ``group``, sorted by name (one per name: the first found)."""
    seen: dict[str, metadata.EntryPoint] = {}
    for ep in metadata.entry_points(group=group):
        seen.setdefault(ep.name, ep)
    return [seen[k] for k in sorted(seen)]


def origin(ep: metadata.EntryPoint) -> str:
    """``name = value (package version)`` of an entry point, for messages."""
    dist = getattr(ep, "dist", None)
    pkg = f" ({dist.name} {dist.version})" if dist is not None else ""
    return f"{ep.group} {ep.name!r} = {ep.value!r}{pkg}"


def _load(ep: metadata.EntryPoint, kind: type) -> Any:
    obj = ep.load()
    if not isinstance(obj, kind) and callable(obj) and not isinstance(obj, type):
        obj = obj()
    if not isinstance(obj, kind):
        raise TypeError(f"is a {type(obj).__name__}, not a {kind.__name__}")
    return obj


def register(registry: dict[str, Any], role: str, kind: type, taken: set[str]) -> list[str]:
    """Add the installed plug-ins of ``role`` ("filter" or "associator") to ``registry`` (name -> ``kind``
    instance); ``taken``: names no plug-in may use (the built-ins, wrapper names). Returns the names added."""
    added = []
    for ep in entry_points(GROUPS[role]):
        why = None
        if not NAME.match(ep.name):
            why = "its name must be lower-case letters and digits joined by single hyphens"
        elif ep.name in taken or ep.name in registry:
            why = f"{ep.name!r} is already a {role}"
        else:
            try:
                registry[ep.name] = _load(ep, kind)
                added.append(ep.name)
                continue
            except Exception as err:  # noqa: BLE001 - any failure of foreign code skips that plug-in
                why = f"{type(err).__name__}: {str(err).splitlines()[0] if str(err) else ''}".rstrip(": ")
        warnings.warn(f"plug-in skipped: {origin(ep)}: {why}", PluginWarning, stacklevel=2)
    return added


PLUGINS: dict[str, tuple[str, ...]] = {"filter": (), "associator": ()}
"""The plug-in names registered, per role: at import from entry points, then by :func:`register_filter` and
:func:`register_associator` (``testbed trackers`` lists their combinations)."""
BUILTINS: dict[str, frozenset[str]] = {"filter": frozenset(), "associator": frozenset()}
"""The built-in names per role (and the wrappers'), which no plug-in may take."""
_FROM_PYTHON: set[tuple[str, str]] = set()


def register_filter(name: str, kind) -> None:
    """Add the filter ``kind`` (a trackers.filters.FilterKind) as ``name`` in this process, as an installed
    plug-in adds one: ``<associator>-<name>`` is then a tracker name for every associator (``jpda-<name>``) and
    its parameters are loaded and bounded like the built-ins'. Registering a name again from Python replaces
    it; ValueError (one line) for an invalid name, a built-in's or an installed plug-in's, TypeError for a kind
    of the wrong type (docs/api.md, "Plug-in filters and associators")."""
    from roadtrack.trackers.filters import FILTERS
    from roadtrack.trackers.filters.params import FilterKind

    _register("filter", name, kind, FILTERS, FilterKind)


def register_associator(name: str, kind) -> None:
    """Add the associator ``kind`` (a trackers.association.AssociatorKind) as ``name`` in this process:
    ``<name>-<filter>`` is then a tracker name for every filter. Errors as :func:`register_filter`."""
    from roadtrack.trackers.association.roles import ASSOCIATORS, AssociatorKind

    _register("associator", name, kind, ASSOCIATORS, AssociatorKind)


def _register(role: str, name: str, kind, registry: dict, kind_type: type) -> None:
    if not isinstance(name, str) or not NAME.match(name):
        raise ValueError(f"{role} name {name!r}: use lower-case letters and digits joined by single hyphens")
    if name in BUILTINS[role]:
        raise ValueError(f"{name!r} is a built-in {role} (or wrapper) name; choose another")
    if name in registry and (role, name) not in _FROM_PYTHON:
        raise ValueError(f"{name!r} is already a {role} (an installed plug-in's); choose another")
    if not isinstance(kind, kind_type):
        raise TypeError(f"{role} {name!r}: expected a {kind_type.__module__}.{kind_type.__name__}, got a "
                        f"{type(kind).__name__}")
    if not (dataclasses.is_dataclass(kind.params) and isinstance(kind.params, type)):
        raise TypeError(f"{role} {name!r}: its params must be a dataclass (trackers.params.param fields)")
    registry[name] = kind
    _FROM_PYTHON.add((role, name))
    if name not in PLUGINS[role]:
        PLUGINS[role] = (*PLUGINS[role], name)


def load_all(wrappers) -> None:
    """Register the installed filter and associator plug-ins (called once, when ``trackers`` is imported);
    ``wrappers``: the wrapper names (trackers.registry.WRAPPERS), which no plug-in may take."""
    from roadtrack.trackers.association.roles import ASSOCIATORS, AssociatorKind
    from roadtrack.trackers.filters import FILTERS
    from roadtrack.trackers.filters.params import FilterKind

    taken = set(wrappers)
    BUILTINS["filter"] = frozenset(taken | set(FILTERS))
    BUILTINS["associator"] = frozenset(taken | set(ASSOCIATORS))
    PLUGINS["filter"] = tuple(register(FILTERS, "filter", FilterKind, taken | set(FILTERS)))
    PLUGINS["associator"] = tuple(register(ASSOCIATORS, "associator", AssociatorKind, taken | set(ASSOCIATORS)))
