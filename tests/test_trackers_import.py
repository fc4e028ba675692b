"""Our `trackers` is this repository's package, installed as roadtrack.trackers (not PyPI's `trackers`, issue 31.1;
tests/test_namespace.py runs both in one environment), and depends on numpy/scipy only."""

import ast
import sys
from pathlib import Path

from roadtrack import trackers

REPO = Path(__file__).resolve().parents[1]
FORBIDDEN = {"open3d", "rerun", "highway_env", "gymnasium", "sensors", "testbed"}


def imported_top_level_modules(path: Path) -> set[str]:
    """Top-level names of a file's absolute imports, roadtrack.X counted as X."""
    names = set()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            names |= {a.name.removeprefix("roadtrack.").split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module.removeprefix("roadtrack.").split(".")[0])
    return names


def test_trackers_resolves_inside_this_repository():
    path = Path(trackers.__file__).resolve()
    assert trackers.__name__ == "roadtrack.trackers"
    assert path == REPO / "trackers" / "__init__.py"
    assert "site-packages" not in str(path)


def test_trackers_imports_only_numpy_scipy_and_the_standard_library():
    files = sorted((REPO / "trackers").rglob("*.py"))
    assert len(files) >= 12
    used = set().union(*(imported_top_level_modules(f) for f in files))
    assert not used & FORBIDDEN
    assert used - set(sys.stdlib_module_names) <= {"numpy", "scipy", "trackers"}, used


def test_public_names_are_exported():
    for name in trackers.__all__:
        assert hasattr(trackers, name), name
