"""The house's rules (docs/development.md, "The map of the house"): imports go down the layers and never
round in a cycle, a module holds one concept (at most 500 lines), a package at most 15 modules, and the
service never imports torch. Every import counts, a function's own and a type checker's included: an import
deferred into a function hides an arrow, it does not remove it."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("index", "service", "training", "evaluation", "posedesc", "benchmarks")

#: what each top-level package may import of the others (itself always)
MAY_IMPORT = {
    "index": set(),
    "service": {"index"},
    "training": {"index"},
    "evaluation": {"index", "service"},
    "benchmarks": {"index", "service", "training", "evaluation"},
    "posedesc": {"index", "service", "training", "evaluation", "benchmarks"},
}
#: index's rooms, lowest first: a room may import only the rooms before it (the package's docstring)
INDEX_ROOMS = ("geometry", "features", "store", "templates", "draw", "refine", "data")
MAX_LINES = 500
MAX_MODULES = 15


def module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imported(path: Path) -> set[str]:
    """Every absolute module name `path` imports, and for `from a import b` also a.b."""
    out: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            out |= {node.module} | {f"{node.module}.{a.name}" for a in node.names}
    return out


def imports(path: Path, modules: set[str]) -> set[str]:
    """The project modules `path` imports (`from a import b` names the module a.b when there is one)."""
    out: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names if a.name in modules}
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            subs = {f"{node.module}.{a.name}" for a in node.names} & modules
            out |= subs or ({node.module} & modules)
    return out


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan's algorithm)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    found: list[list[str]] = []

    def visit(v: str) -> None:
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
            component = []
            while True:
                w = stack.pop()
                on.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1 or v in graph[v]:
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def source_files() -> list[Path]:
    return [p for pkg in PACKAGES for p in (ROOT / pkg).rglob("*.py")]


def project_graph() -> dict[str, set[str]]:
    files = source_files()
    modules = {module_name(p) for p in files}
    return {module_name(p): imports(p, modules) - {module_name(p)} for p in files}


def arrows_up(graph: dict[str, set[str]]) -> list[str]:
    """Every import against the layers: between top-level packages (`MAY_IMPORT`) and between index's rooms."""
    bad = []
    for a, targets in graph.items():
        for b in targets:
            pa, pb = a.split(".")[0], b.split(".")[0]
            if pa != pb and pb not in MAY_IMPORT[pa]:
                bad.append(f"{a} -> {b}")
            elif pa == pb == "index":
                ra, rb = (m.split(".")[1] if m.count(".") else "" for m in (a, b))
                if ra and rb and ra != rb and INDEX_ROOMS.index(rb) > INDEX_ROOMS.index(ra):
                    bad.append(f"{a} -> {b}")
                if (
                    not ra and rb and a != "index"
                ):  # a loose module of index/ (none today) is a room of its own
                    bad.append(f"{a} -> {b}")
    return sorted(bad)


def test_cycles_are_found():
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert cycles({"a": {"b"}, "b": set()}) == []


def test_arrows_up_are_found():
    assert arrows_up({"index.geometry.pose": {"index.store.search"}}) == [
        "index.geometry.pose -> index.store.search"
    ]
    assert arrows_up({"index.refine.fit": {"index.geometry.pose"}}) == []
    assert arrows_up({"benchmarks.fit": {"posedesc.commands.evaluate"}}) == [
        "benchmarks.fit -> posedesc.commands.evaluate"
    ]
    assert arrows_up({"service.state": {"training.model"}}) == ["service.state -> training.model"]


def test_no_module_imports_itself_back():
    graph = project_graph()
    assert "evaluation.run" in graph and "evaluation.served" in graph["evaluation.run"]
    assert cycles(graph) == []


def test_imports_go_down_the_layers():
    graph = project_graph()
    assert "index.templates.register" in graph and "index.store" in graph["index.templates.register"]
    assert arrows_up(graph) == []


def test_the_service_never_imports_torch():
    """The serving image carries onnxruntime, not torch (deploy/requirements-serve.txt)."""
    heavy = {"torch", "onnxscript"}
    for path in (ROOT / "service").rglob("*.py"):
        assert not {n.split(".")[0] for n in imported(path)} & heavy, path
    for path in (ROOT / "index").rglob("*.py"):
        assert not {n.split(".")[0] for n in imported(path)} & heavy, path


def test_one_concept_a_module_and_small_rooms():
    files = source_files() + sorted((ROOT / "scripts").glob("*.py"))
    long = {str(p.relative_to(ROOT)): n for p in files if (n := len(p.read_text().splitlines())) > MAX_LINES}
    assert long == {}
    crowded = {}
    for folder in {p.parent for p in files}:
        n = len([p for p in folder.glob("*.py") if p.name != "__init__.py"])
        if n > MAX_MODULES:
            crowded[str(folder.relative_to(ROOT))] = n
    assert crowded == {}


def test_one_word_one_thing():
    """No two classes of index/ and service/ share a name, and there is one box IoU
    (`index.geometry.boxes.iou`): a word that means two things is read as the wrong one."""
    seen: dict[str, list[str]] = {}
    functions: dict[str, list[str]] = {}
    for path in [p for pkg in ("index", "service", "evaluation") for p in (ROOT / pkg).rglob("*.py")]:
        tree = ast.parse(path.read_text())
        for node in tree.body:
            where = str(path.relative_to(ROOT))
            if isinstance(node, ast.ClassDef) and path.parts[len(ROOT.parts)] in ("index", "service"):
                seen.setdefault(node.name, []).append(where)
            if isinstance(node, ast.FunctionDef):
                functions.setdefault(node.name, []).append(where)
    assert {k: v for k, v in seen.items() if len(v) > 1} == {}
    assert functions.get("iou") == ["index/geometry/boxes.py"]
