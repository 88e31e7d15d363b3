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


#: the top-level modules every layer shares (they import only each other and the models)
SHARED = {
    "banded_linalg",
    "binomial",
    "code_hashing",
    "estimator_moments",
    "io",
    "kernels",
    "log",
    "openblas_threads",
    "seeds",
}
#: subpackage -> the subpackages and top-level modules it may import (beside the shared
#: top-level modules); the
#: layers, lowest first: models, stan_backends; nuts, joint_map, exact, model_check; config;
#: design; reports; stages.  A package's ``__main__`` (its command line) is no layer: it may
#: import anything and nothing imports it.
ALLOWED = {
    "models": set(),
    "stan_backends": set(),
    "nuts": {"models", "stan_backends"},
    "joint_map": {"models"},
    "exact": {"models"},
    "model_check": {"models", "stan_backends", "nuts"},
    # config: a model without a Stan program is refused when no program can be generated
    # for it (nuts.analytic_program.generation_problem)
    "config": {"models", "stan_backends", "model_check", "nuts"},
    "design": {"models", "config"},
    "reports": {"models", "config", "joint_map", "nuts", "cache_keys", "stage_code"},
    "stages": {
        "models",
        "stan_backends",
        "nuts",
        "joint_map",
        "exact",
        "config",
        "design",
        "reports",
    },
}


def _layer(module: str) -> str:
    """The subpackage a module lies in, or its own name for a top-level module."""
    parts = module.split(".")[1:]
    return parts[0] if parts else ""


def direction_problems(graph: dict[str, set[str]], package_dir: Path) -> list[str]:
    """Every import that goes against :data:`ALLOWED` or :data:`SHARED`: a subpackage that
    imports a subpackage it may not, or a top-level module other than the shared ones; a
    shared module that imports anything but the shared modules and the models.  The stages
    (the glue) may import any top-level module."""
    subpackages = {p.parent.name for p in package_dir.glob("*/__init__.py")}
    problems = []
    for module, targets in sorted(graph.items()):
        source = _layer(module)
        if module.endswith(".__main__") or not source:
            continue
        for target in sorted(targets):
            layer = _layer(target)
            if target.endswith(".__main__"):
                problems.append(f"{module} imports the command line {target}")
            elif not layer or layer == source:
                continue
            elif source in SHARED:
                if layer not in SHARED and layer != "models":
                    problems.append(f"shared module {module} imports {target}")
            elif source in subpackages:
                allowed = ALLOWED.get(source, set())
                if layer in subpackages and layer not in allowed:
                    problems.append(f"{module} ({source}) imports {target} ({layer})")
                elif layer not in subpackages | SHARED | allowed and source != "stages":
                    problems.append(f"{module} ({source}) imports top-level {target}")
    return problems


def test_the_subpackages_import_in_the_allowed_directions():
    graph = import_graph(PACKAGE_DIR)
    subpackages = {p.parent.name for p in PACKAGE_DIR.glob("*/__init__.py")}
    assert subpackages == set(ALLOWED), "every subpackage has its allowed imports"
    assert direction_problems(graph, PACKAGE_DIR) == []
    # the one import that would close a circle between two subpackages is in a command line
    assert "ssmobs.config.validation" in graph["ssmobs.model_check.__main__"]
    assert "ssmobs.model_check.python" in graph["ssmobs.config.validation"]


def test_an_import_against_the_direction_is_found(tmp_path: Path):
    package = tmp_path / "ssmobs"
    for sub in ("models", "nuts", "stages"):
        (package / sub).mkdir(parents=True)
        (package / sub / "__init__.py").write_text("")
    (package / "__init__.py").write_text("")
    (package / "io.py").write_text("from .models import base\n")
    (package / "models" / "base.py").write_text("")
    (package / "nuts" / "run.py").write_text("def f():\n    from ..stages import glue\n")
    (package / "stages" / "glue.py").write_text("from ..nuts import run\nfrom .. import io\n")
    (package / "tables.py").write_text("from .nuts import run\n")
    (package / "seeds.py").write_text("from . import tables\n")
    problems = direction_problems(import_graph(package), package)
    assert problems == [
        "ssmobs.nuts.run (nuts) imports ssmobs.stages (stages)",
        "ssmobs.nuts.run (nuts) imports ssmobs.stages.glue (stages)",
        "shared module ssmobs.seeds imports ssmobs.tables",
    ]
