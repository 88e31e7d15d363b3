"""The package's import graph has no circle (issue 37): imports inside functions and under
``if TYPE_CHECKING:`` count, so a circle cannot hide behind a late import."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest
from repo_paths import PACKAGE_DIR

pytestmark = pytest.mark.unit


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
    assert not any(_layer(t) == "stages" for t in graph["ssmobs.config.validation"])
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
#: every subpackage and every other top-level module -> the subpackages and top-level modules
#: it may import beside the shared ones.  The layers, lowest first: models, stan_backends;
#: nuts, joint_map, exact, k_selection, housekeeping; config; stage_table (the table of
#: stages and their inputs builders), stage_code; model_check (its command line reads a
#: config), design, provenance, cache_keys; run_paths, reports; stages (the glue).  A
#: package's ``__main__`` (its command line) follows its package's row, and nothing imports
#: it.
ALLOWED: dict[str, set[str]] = {
    "models": set(),
    "stan_backends": set(),
    "nuts": {"models", "stan_backends"},
    "joint_map": {"models"},
    "exact": {"models"},
    "k_selection": {"models"},
    "stage_table": {"config"},
    "stage_code": {"stage_table"},
    "housekeeping": {"stan_backends"},
    # a model without a Stan program is refused when no program can be generated for it
    # (nuts.analytic_program.generation_problem); a user's model is checked against itself
    # (models.self_check)
    "config": {"models", "stan_backends", "nuts"},
    "model_check": {"models", "stan_backends", "nuts", "config"},
    "design": {"models", "config"},
    "provenance": {"config", "stan_backends"},
    "cache_keys": {"config", "nuts", "stan_backends", "stage_code", "stage_table"},
    "run_paths": {"config", "nuts", "cache_keys", "stage_table"},
    "reports": {"models", "config", "joint_map", "nuts", "cache_keys", "stage_code"},
    "stages": {
        "models",
        "stan_backends",
        "nuts",
        "joint_map",
        "exact",
        "k_selection",
        "config",
        "design",
        "reports",
    },
}


def _layer(module: str) -> str:
    """The subpackage a module lies in, or its own name for a top-level module ("" for the
    package's ``__init__``)."""
    parts = module.split(".")[1:]
    return parts[0] if parts else ""


def _is_package(module: str, package_dir: Path) -> bool:
    return (package_dir.joinpath(*module.split(".")[1:]) / "__init__.py").is_file()


def direction_problems(graph: dict[str, set[str]], package_dir: Path) -> list[str]:
    """Every import against :data:`ALLOWED` and :data:`SHARED`, with no exception: a layer
    (subpackage or top-level module) that imports a layer its row does not name, a shared
    module that imports anything but the shared modules and the models, a module of a layer
    without a row, an import of a command line (``__main__``), and a stage module that
    imports another stage (only the ``__init__`` of its packages, which run no stage)."""
    problems = []
    for module, targets in sorted(graph.items()):
        source = _layer(module)
        if not source:
            continue  # the package's __init__ (a version string)
        if source not in ALLOWED and source not in SHARED:
            problems.append(f"{module} lies in no layer of ALLOWED or SHARED")
            continue
        for target in sorted(targets):
            layer = _layer(target)
            if target.endswith(".__main__"):
                problems.append(f"{module} imports the command line {target}")
            elif layer == source:
                if source == "stages" and not _is_package(target, package_dir):
                    problems.append(f"stage {module} imports the stage {target}")
            elif not layer:
                continue
            elif source in SHARED:
                if layer not in SHARED and layer != "models":
                    problems.append(f"shared module {module} imports {target}")
            elif layer not in SHARED and layer not in ALLOWED[source]:
                problems.append(f"{module} ({source}) imports {target} ({layer})")
    return problems


def test_every_layer_has_a_row_and_the_rows_have_an_order():
    top_level = {p.stem for p in PACKAGE_DIR.glob("*.py") if p.stem != "__init__"}
    subpackages = {p.parent.name for p in PACKAGE_DIR.glob("*/__init__.py")}
    assert set(ALLOWED) | SHARED == subpackages | top_level
    assert not set(ALLOWED) & SHARED
    assert {"cache_keys", "run_paths", "stage_code", "provenance", "housekeeping"} <= set(ALLOWED)
    order: list[str] = []  # a layer after everything it may import: no circle of layers
    left = dict(ALLOWED)
    while left:
        ready = sorted(n for n, deps in left.items() if deps <= set(order))
        assert ready, f"the rows of ALLOWED form a circle among {sorted(left)}"
        order += ready
        for n in ready:
            del left[n]


def test_the_layers_import_in_the_allowed_directions():
    graph = import_graph(PACKAGE_DIR)
    assert direction_problems(graph, PACKAGE_DIR) == []
    # the command line of the model check reads a config; the config does not import it
    assert "ssmobs.config.validation" in graph["ssmobs.model_check.__main__"]
    assert "ssmobs.models.self_check" in graph["ssmobs.config.validation"]
    assert not any(t.startswith("ssmobs.model_check") for t in graph["ssmobs.config.validation"])


def test_an_import_against_the_direction_is_found(tmp_path: Path):
    package = tmp_path / "ssmobs"
    for sub in ("models", "nuts", "stages", "stages/outputs", "model_check"):
        (package / sub).mkdir(parents=True)
        (package / sub / "__init__.py").write_text("")
    (package / "__init__.py").write_text("")
    (package / "io.py").write_text("from .models import base\n")
    (package / "models" / "base.py").write_text("")
    (package / "model_check" / "__main__.py").write_text("from ..nuts import run\n")
    (package / "nuts" / "run.py").write_text("def f():\n    from ..stages import glue\n")
    (package / "stages" / "glue.py").write_text("from ..nuts import run\nfrom .. import io\n")
    (package / "stages" / "outputs" / "table.py").write_text(
        "from .. import glue\nfrom ..outputs import __init__\n"
    )
    (package / "stages" / "other.py").write_text("from ..model_check import __main__\n")
    (package / "tables.py").write_text("from .nuts import run\n")
    (package / "seeds.py").write_text("from . import tables\n")
    (package / "cache_keys.py").write_text("from .stages import glue\n")
    problems = direction_problems(import_graph(package), package)
    assert problems == [
        "ssmobs.cache_keys (cache_keys) imports ssmobs.stages (stages)",
        "ssmobs.cache_keys (cache_keys) imports ssmobs.stages.glue (stages)",
        "ssmobs.nuts.run (nuts) imports ssmobs.stages (stages)",
        "ssmobs.nuts.run (nuts) imports ssmobs.stages.glue (stages)",
        "shared module ssmobs.seeds imports ssmobs.tables",
        "ssmobs.stages.other (stages) imports ssmobs.model_check (model_check)",
        "ssmobs.stages.other imports the command line ssmobs.model_check.__main__",
        "stage ssmobs.stages.outputs.table imports the stage ssmobs.stages.glue",
        "ssmobs.tables lies in no layer of ALLOWED or SHARED",
    ]
