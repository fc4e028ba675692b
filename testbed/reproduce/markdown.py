"""Markdown pieces the reproductions' summary.md files share.

    table(header, rows, blank=True) -> list[str]    a pipe table (cells str()-ed), a blank line after it
"""
from __future__ import annotations


def table(header: list[str], rows: list[list], blank: bool = True) -> list[str]:
    """A markdown pipe table of ``header`` and ``rows`` (each cell str()-ed), with a blank line after it
    unless ``blank`` is False."""
    out = ["| " + " | ".join(str(h) for h in header) + " |", "|" + "---|" * len(header)]
    return out + ["| " + " | ".join(str(c) for c in r) + " |" for r in rows] + ([""] if blank else [])
