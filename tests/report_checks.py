"""What every reproduction test checks of a written report (imported by tests/test_reproduce_*.py)."""
from __future__ import annotations

from pathlib import Path


def read_report(path: Path, figures, headings) -> str:
    """summary.md at ``path``, after asserting that each of ``figures`` is a real PNG (> 10 kB) beside it and named
    in the text, and that each of ``headings`` is in the text."""
    md = Path(path).read_text()
    for png in figures:
        data = (Path(path).parent / png).read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 10_000, png
        assert f"`{png}`" in md, png
    for heading in headings:
        assert heading in md, heading
    return md
