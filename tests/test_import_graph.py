"""The package's module import graph, built from the source with ast (nothing is imported).

Edges are every ``import`` of an fgins module anywhere in a file, at module level or deferred
inside a function (a deferred import is still a dependency; it only hides a cycle from the
interpreter). Imports under ``if TYPE_CHECKING:`` are left out: they never run.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SKIP_DIRS = {"tests", "scripts", "build", ".venv", "venv", ".git", "out"}

# Declared up-calls that would otherwise close a cycle, with why they are there.
ALLOWED_EDGES = {
    # Trajectory.write()/to_dataframe()/summary() are the API's entry points on the data
    # model (issue 11); they import fgins.api inside the method, on use.
    ("fgins.datatypes", "fgins.api"),
}
# GTSAM outside factors/ and graph/ found on main when this test was written; each is a
# design violation to fix, listed so that a *new* one fails here.
KNOWN_GTSAM_OFFENDERS: set[str] = set()


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(["fgins", *parts])


def package_files() -> dict[str, Path]:
    files = {}
    for path in sorted(ROOT.rglob("*.py")):
        relative = path.relative_to(ROOT)
        if relative.parts[0] in SKIP_DIRS or any(p.startswith(".") for p in relative.parts):
            continue
        files[_module_name(path)] = path
    return files


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"
    )


class _Imports(ast.NodeVisitor):
    def __init__(self, module: str, is_package: bool) -> None:
        self.module = module
        self.is_package = is_package
        self.names: list[tuple[str, str | None]] = []  # (module, imported name or None)

    def visit_If(self, node: ast.If) -> None:
        if _is_type_checking(node.test):
            for child in node.orelse:
                self.visit(child)
            return
        self.generic_visit(node)

    def visit_Import(self, node: ast.Import) -> None:
        for alias in node.names:
            self.names.append((alias.name, None))

    def visit_ImportFrom(self, node: ast.ImportFrom) -> None:
        base = node.module or ""
        if node.level:
            package = self.module.split(".")
            if not self.is_package:
                package = package[:-1]
            package = package[: len(package) - (node.level - 1)]
            base = ".".join(package + ([base] if base else []))
        for alias in node.names:
            self.names.append((base, alias.name))


def import_graph() -> tuple[dict[str, set[str]], dict[str, set[str]]]:
    """(fgins module -> fgins modules it imports, fgins module -> top-level external imports)."""
    files = package_files()
    graph: dict[str, set[str]] = {name: set() for name in files}
    external: dict[str, set[str]] = {name: set() for name in files}
    for name, path in files.items():
        visitor = _Imports(name, path.name == "__init__.py")
        visitor.visit(ast.parse(path.read_text(), filename=str(path)))
        for module, imported in visitor.names:
            if module == "fgins" or module.startswith("fgins."):
                target = f"{module}.{imported}" if imported else module
                if target in files:  # `from fgins.io import nmea` imports a module
                    graph[name].add(target)
                elif module in files:
                    graph[name].add(module)
            else:
                external[name].add(module.split(".")[0])
        graph[name].discard(name)
    return graph, external


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []
    counter = 0
    for root in graph:
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            advanced = False
            for child in children:
                if child not in index:
                    index[child] = low[child] = counter
                    counter += 1
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph[child]))))
                    advanced = True
                    break
                if child in on_stack:
                    low[node] = min(low[node], index[child])
            if advanced:
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                component = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    component.append(member)
                    if member == node:
                        break
                if len(component) > 1:
                    found.append(sorted(component))
    return found


def test_cycle_finder_finds_a_planted_cycle():
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}, "e": set()}
    assert cycles(graph) == [["a", "b", "c"]]
    assert cycles({"a": {"b"}, "b": set()}) == []


def test_graph_sees_deferred_imports():
    graph, _ = import_graph()
    # pipeline imports the graph smoother only inside run_method: still an edge.
    assert "fgins.graph.smoother" in graph["fgins.pipeline"]
    assert "fgins.datatypes" in graph["fgins.api"]


def test_no_import_cycles_among_fgins_modules():
    graph, _ = import_graph()
    for source, target in ALLOWED_EDGES:
        graph[source].discard(target)
    assert cycles(graph) == []


def test_allowed_up_calls_are_still_needed():
    graph, _ = import_graph()
    for source, target in ALLOWED_EDGES:
        assert target in graph[source], f"{source} -> {target} is gone; drop it from the list"


def test_gtsam_only_in_factors_and_graph():
    _, external = import_graph()
    offenders = {
        name
        for name, modules in external.items()
        if "gtsam" in modules and not name.startswith(("fgins.factors", "fgins.graph"))
    }
    assert offenders <= KNOWN_GTSAM_OFFENDERS, (
        f"new GTSAM import outside factors/, graph/: {offenders - KNOWN_GTSAM_OFFENDERS}"
    )


def test_import_fgins_is_light():
    import subprocess
    import sys

    code = (
        "import sys, fgins; heavy = [m for m in ('numpy', 'gtsam', 'matplotlib', 'pandas') "
        "if m in sys.modules]; print(','.join(heavy))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == ""
