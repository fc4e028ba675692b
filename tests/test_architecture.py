"""The tree shows the architecture (docs/architecture.md): testbed's stage packages import only downwards, no
import cycle between modules, no private name used outside its module, and the libraries stay independent.

Every import statement is read from the source (function-local and TYPE_CHECKING ones included), so an import
that only runs on some path still counts.
"""
from __future__ import annotations

import ast
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
LAYERS = ("config", "common", "scenario", "world", "sensing", "tracking", "scoring", "recording", "pipeline",
          "export", "perception", "campaign", "reproduce", "cli")
"""testbed's stage packages, lowest first: a package imports only those before it (and itself)."""


def _modules(package: str) -> dict[str, Path]:
    out = {}
    for p in sorted((REPO / package).rglob("*.py")):
        parts = p.relative_to(REPO).with_suffix("").parts
        out[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = p
    return out


def _imports(name: str, path: Path) -> list[tuple[str, str]]:
    """(imported module, imported name or '') of every import in the file."""
    pkg = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
    out = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = pkg.split(".")
                mod = ".".join(base[: len(base) - node.level + 1] + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            out += [(mod, a.name) for a in node.names]
        elif isinstance(node, ast.Import):
            out += [(a.name, "") for a in node.names]
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
            if attr.startswith("_") and not attr.startswith("__") and mod.split(".")[0] in ("testbed", "sensors",
                                                                                          "trackers"):
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
    for package in ("testbed", "sensors", "trackers"):
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
