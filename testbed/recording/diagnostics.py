"""Per-track diagnostics in the viewer: one plot per quantity, one line per confirmed track's slot.

A tracker's diagnostics (``TrackSet.diagnostics``: score, NIS, gate volume, boundary layers, mode
probabilities, association weights, the KS regime's statistics, ...) are grouped by quantity; each group is
one time-series plot of the blueprint (a tab of the "track diagnostics" panel), so quantities of different
units and sizes never share an axis. Each diagnostic name has one series per slot,
``diagnostics/<group>/<name>/<k>`` (testbed/recording/slots.py: a confirmed track holds a slot, and its colour,
for its life); ``diagnostics/slots/track_id/<k>`` holds the track id in slot k. An IMM's per-mode names
(``cv.psi_z_0``, ``ct.psi_y_1``) go to the group of the quantity after the mode prefix. A name no group
claims goes to ``other``.

    group_of(name) -> str             the group key of a diagnostic name
    series_path(name) -> str          diagnostics/<group>/<name> (slot k's series: series_path(name)/<k>)
    series_label(name, k) -> str      slot k's line name, e.g. "ct psi z 0, slot 3"
    GROUPS                            (key, plot title with units, test) in tab order
"""
from __future__ import annotations

import functools
import re
from typing import Callable

_MODE = re.compile(r"^[A-Za-z][A-Za-z0-9_-]*\.")  # an IMM mode prefix, e.g. "ct."


def _base(name: str) -> str:
    return _MODE.sub("", name)


GROUPS: tuple[tuple[str, str, Callable[[str], bool]], ...] = (
    ("score", "track score (log-likelihood ratio)", lambda b: b == "score"),
    ("nis", "NIS: normalised innovation squared (chi-square, m dof)", lambda b: b == "nis"),
    ("gate", "gate volume [m^2]", lambda b: b == "gate_volume"),
    ("position_std", "position std [m]", lambda b: b == "position_std"),
    ("association", "association: miss weight w0, gated count, P_D", lambda b: b in ("w0", "n_gated", "pd")),
    ("modes", "IMM mode probabilities mu", lambda b: b.startswith("mu_")),
    ("layer_z", "SVSF layer psi_z, measured partition [m]", lambda b: b.startswith("psi_z")),
    ("layer_y", "SVSF layer psi_y, unmeasured partition [state units: m/s, rad, rad/s]",
     lambda b: b.startswith(("psi_y", "psi_v"))),
    ("chatter", "SVSF chattering (5.37) [m]", lambda b: b.startswith("chatter")),
    ("svsf_regime", "SVSF regime (1 robust, 0 optimal)", lambda b: b.startswith("regime")),
    ("ks", "KS track regime: D_T, D_L, d_n (paper 002), regime 1/0/-1", lambda b: b.startswith("ks_")),
)
OTHER = ("other", "other diagnostics")


@functools.lru_cache(maxsize=4096)
def group_of(name: str) -> str:
    """The key of the group (:data:`GROUPS`) of diagnostic ``name``; "other" if none claims it."""
    base = _base(name)
    for key, _, test in GROUPS:
        if test(base):
            return key
    return OTHER[0]


SLOT_IDS = "diagnostics/slots/track_id"  # slot k's track id at SLOT_IDS/<k>
SLOTS = ("slots", "track id per slot (hover a line: its track; a slot's colour is its track's in the scene)")


def series_path(name: str) -> str:
    """The entity path of diagnostic ``name``'s series: ``diagnostics/<group>/<name>`` (slot k's at ``/<k>``)."""
    return f"diagnostics/{group_of(name)}/{name}"


def series_label(name: str, k: int) -> str:
    """The name of slot ``k``'s line of ``name``: ``<name>, slot <k>`` with the mode's dot and underscores as
    spaces (what hovering a line shows)."""
    return f"{name.replace('.', ' ').replace('_', ' ')}, slot {k}"


def titles() -> list[tuple[str, str]]:
    """(key, title) of every group, of "other" and of the slots' track ids, in tab order."""
    return [(k, t) for k, t, _ in GROUPS] + [OTHER, SLOTS]
