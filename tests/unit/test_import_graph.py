"""The package's import graph has no circle (issue 37): imports inside functions and under
``if TYPE_CHECKING:`` count, so a circle cannot hide behind a late import."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

pytestmark = pytest.mark.unit

PACKAGE_DIR = Path(__file__).resolve().parents[2] / "workflow" / "ssmobs"


def _module_name(path: Path, package_dir: Path) -> str:
    parts = [package_dir.name, *path.relative_to(package_dir).with_suffix("").parts]
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def import_graph(package_dir: Path) -> dict[str, set[str]]:
    """Module -> the package's modules it imports anywhere in its file (dotted names)."""
    files = {_module_name(p, package_dir): p for p in sorted(package_dir.rglob("*.py"))}
    graph: dict[str, set[str]] = {}
    for name, path in files.items():
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        targets: set[str] = set()
        for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
            if isinstance(node, ast.Import):
                targets |= {alias.name for alias in node.names}
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    anchor = package.split(".")[: len(package.split(".")) - node.level + 1]
                    base = ".".join([*anchor, *([node.module] if node.module else [])])
                else:
                    base = node.module or ""
                targets.add(base)
                targets |= {f"{base}.{alias.name}" for alias in node.names}  # submodules
        graph[name] = {t for t in targets if t in files and t != name}
    return graph


def circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan), sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for nxt in sorted(graph[node]):
            if nxt not in index:
                visit(nxt)
                low[node] = min(low[node], low[nxt])
            elif nxt in on_stack:
                low[node] = min(low[node], index[nxt])
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

    for node in sorted(graph):
        if node not in index:
            visit(node)
    return sorted(found)


def test_the_package_imports_in_no_circle():
    graph = import_graph(PACKAGE_DIR)
    assert circles(graph) == [], "import circles (imports inside functions count)"
    assert len(graph) > 50 and "ssmobs.models" in graph["ssmobs.config.scenario"]
    assert (
        "ssmobs.design.trajectories" in graph["ssmobs.stages.design"]
    )  # imported inside a function


def test_the_ground_floor_imports_nothing_of_the_package():
    graph = import_graph(PACKAGE_DIR)
    assert graph["ssmobs.config.schema"] == set()
    assert graph["ssmobs.config.files"] == {"ssmobs.config.schema"}
    assert "ssmobs.observability_map" not in graph  # the map's stage is in ssmobs.stages
    assert not graph["ssmobs.config.validation"] & {
        "ssmobs.stages.observability_map",
        "ssmobs.stages",
    }
    for backend in ("native", "cmdstanpy", "pystan"):  # the package imports them, not back
        assert "ssmobs.stan_backends" not in graph[f"ssmobs.stan_backends.{backend}"]


def test_a_circle_behind_late_imports_is_found(tmp_path: Path):
    package = tmp_path / "pkg"
    (package / "sub").mkdir(parents=True)
    (package / "__init__.py").write_text("")
    (package / "a.py").write_text("from .sub import b\n")
    (package / "sub" / "__init__.py").write_text("")
    (package / "sub" / "b.py").write_text("def f():\n    from ..c import g\n")
    (package / "c.py").write_text(
        "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from . import a\n"
    )
    (package / "d.py").write_text("from pkg.c import TYPE_CHECKING\n")
    graph = import_graph(package)
    assert graph["pkg.a"] == {"pkg.sub", "pkg.sub.b"}
    assert graph["pkg.d"] == {"pkg.c"}
    assert circles(graph) == [["pkg.a", "pkg.c", "pkg.sub.b"]]
