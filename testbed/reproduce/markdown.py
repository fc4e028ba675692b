"""Markdown pieces the reproductions' summary.md files share.

    table(header, rows, blank=True) -> list[str]    a pipe table (cells str()-ed), a blank line after it
    verdict(text, quick=, supported=, n=) -> str    a claim's verdict, or "indicative (n runs): not a verdict" for a
                                                    quick run whose own interval or test does not carry it
"""
from __future__ import annotations


def table(header: list[str], rows: list[list], blank: bool = True) -> list[str]:
    """A markdown pipe table of ``header`` and ``rows`` (each cell str()-ed), with a blank line after it
    unless ``blank`` is False."""
    out = ["| " + " | ".join(str(h) for h in header) + " |", "|" + "---|" * len(header)]
    return out + ["| " + " | ".join(str(c) for c in r) + " |" for r in rows] + ([""] if blank else [])


def indicative(n: int, unit: str = "runs") -> str:
    """The words a quick run prints instead of a verdict its runs cannot carry."""
    return f"indicative ({_count(n, unit)}): not a verdict"


def verdict(text: str, *, quick: bool, supported: bool, n: int, unit: str = "runs") -> str:
    """A claim's verdict ``text`` ("holds", "does not hold", ...). A full run states it as computed. A quick run
    (fewer runs, for a first look) states it, with its n, only when ``supported``: the run's own interval or test
    decides it (e.g. "holds" from an interval that excludes 0, or "does not hold" because the interval lies on
    the contrary side); otherwise it prints ``indicative(n)``."""
    if not quick:
        return text
    return f"{text} (quick run, n = {_count(n, unit)})" if supported else indicative(n, unit)


def _count(n: int, unit: str) -> str:
    """'n unit' with a plural unit's 's' dropped for n == 1 ("1 run", "1 seed", "1 run per car")."""
    if n != 1:
        return f"{n} {unit}"
    word, _, rest = unit.partition(" ")
    return f"1 {word[:-1] if word.endswith('s') else word}" + (f" {rest}" if rest else "")
