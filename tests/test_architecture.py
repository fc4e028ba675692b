"""The tree shows the architecture (docs/architecture.md): testbed's stage packages import only downwards, no
import cycle between modules, no private name used outside its module, the libraries stay independent, and every
import of ours goes through the one installed name, roadtrack (issue 31.1).

Every import statement is read from the source (function-local and TYPE_CHECKING ones included), so an import
that only runs on some path still counts.
"""
from __future__ import annotations

import ast
import re
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
TOPS = ("testbed", "sensors", "trackers")
"""The repository's package folders, installed as roadtrack.testbed, roadtrack.sensors and roadtrack.trackers."""
LAYERS = ("config", "common", "scenario", "world", "sensing", "tracking", "scoring", "recording", "pipeline",
          "export", "perception", "campaign", "reproduce", "cli")
"""testbed's stage packages, lowest first: a package imports only those before it (and itself)."""


def _short(mod: str) -> str:
    """``roadtrack.X.y`` -> ``X.y`` (the folder's name); other names unchanged."""
    return mod[len("roadtrack."):] if mod.startswith("roadtrack.") else mod


def _modules(package: str) -> dict[str, Path]:
    """Module name (without the ``roadtrack.`` prefix) -> file, for one package folder."""
    out = {}
    for p in sorted((REPO / package).rglob("*.py")):
        parts = p.relative_to(REPO).with_suffix("").parts
        out[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = p
    return out


def _imports(name: str, path: Path) -> list[tuple[str, str]]:
    """(imported module without the ``roadtrack.`` prefix, imported name or '') of every import in the file."""
    pkg = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
    out = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = pkg.split(".")
                mod = ".".join(base[: len(base) - node.level + 1] + ([node.module] if node.module else []))
            else:
                mod = _short(node.module or "")
            out += [(mod, a.name) for a in node.names]
        elif isinstance(node, ast.Import):
            out += [(_short(a.name), "") for a in node.names]
    return out


def _graph(package: str) -> tuple[dict[str, set[str]], list[str]]:
    mods = _modules(package)
    graph: dict[str, set[str]] = {m: set() for m in mods}
    private = []
    for name, path in mods.items():
        for mod, attr in _imports(name, path):
            target = f"{mod}.{attr}" if f"{mod}.{attr}" in mods else mod
            if target in mods and target != name:
                graph[name].add(target)
            if attr.startswith("_") and not attr.startswith("__") and mod.split(".")[0] in TOPS:
                private.append(f"{name} imports {mod}.{attr}")
    return graph, private


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    found = []

    def visit(v: str) -> None:  # Tarjan's strongly connected components
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                found.append(sorted(comp))

    for v in graph:
        if v not in index:
            visit(v)
    return found


def test_no_import_cycle_and_no_private_name_across_modules():
    for package in TOPS:
        graph, private = _graph(package)
        assert _cycles(graph) == [], package
        assert private == [], private


def test_every_testbed_module_is_in_a_stage_package_and_imports_only_downwards():
    graph, _ = _graph("testbed")
    top = [m for m in graph if m.count(".") == 1 and not (REPO / "testbed" / m.split(".")[1]).is_dir()]
    assert top == [], f"modules outside the stage packages: {top}"
    assert {m.split(".")[1] for m in graph if m != "testbed"} == set(LAYERS)
    wrong = []
    for name, targets in graph.items():
        if name == "testbed":
            continue  # the public API (testbed/__init__.py) may use any stage
        rank = LAYERS.index(name.split(".")[1])
        for t in targets:
            if t != "testbed" and LAYERS.index(t.split(".")[1]) > rank:
                wrong.append(f"{name} -> {t}")
            if t == "testbed":
                wrong.append(f"{name} -> testbed (the public API is for users)")
    assert wrong == []


def test_each_stage_package_says_its_job_in_its_docstring():
    for layer in LAYERS:
        doc = ast.get_docstring(ast.parse((REPO / "testbed" / layer / "__init__.py").read_text(encoding="utf-8")))
        assert doc and len(doc.split(".")[0]) > 10, layer


def test_the_libraries_know_nothing_of_the_testbed_or_the_simulator():
    banned = {"trackers": ("testbed", "sensors", "highway_env", "gymnasium", "open3d", "rerun"),
              "sensors": ("testbed", "trackers", "highway_env", "gymnasium", "rerun")}
    for package, names in banned.items():
        for name, path in _modules(package).items():
            for mod, _ in _imports(name, path):
                assert mod.split(".")[0] not in names, f"{name} imports {mod}"


IN_STRING_IMPORT = re.compile(r"(?:\\n|;|[\"'])[ \t]*(?:from[ \t]+(?:testbed|sensors|trackers)(?:\.\w+)*[ \t]+import"
                              r"|import[ \t]+(?:testbed|sensors|trackers)\b)")
"""An import statement of a top-level testbed, sensors or trackers in code held by a string ("...\\nfrom X import")."""


def _absolute_imports(path: Path) -> list[str]:
    """The module named by every absolute import statement of a file."""
    out = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom) and not node.level:
            out.append(node.module or "")
        elif isinstance(node, ast.Import):
            out += [a.name for a in node.names]
    return out


def test_every_import_of_ours_names_roadtrack():
    """An installed roadtrack has no top-level testbed, sensors or trackers (PyPI's `trackers` is another
    project): an import of one of them anywhere in the code, tests, benchmarks or examples would run only from a
    checkout, or import someone else's package. Import statements inside strings (code run by a subprocess) count."""
    files = [p for d in (*TOPS, "tests", "benchmarks", "examples") for p in sorted((REPO / d).rglob("*.py"))]
    bad = [f"{p.relative_to(REPO)}: import {m}" for p in files for m in _absolute_imports(p) if m.split(".")[0] in TOPS]
    bad += [f"{p.relative_to(REPO)}: {m.group(0).strip()!r}" for p in files
            for m in IN_STRING_IMPORT.finditer(p.read_text(encoding="utf-8"))]
    assert bad == [] and len(files) > 150, bad
