"""The rule scripts (workflow/scripts/*.py) share one set-up: logging, then the sweep of the
temporaries an interrupted earlier job left beside the outputs."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

pytestmark = pytest.mark.unit

SCRIPTS = sorted((Path(__file__).resolve().parents[2] / "workflow" / "scripts").glob("*.py"))


def _is_call(node: ast.stmt, module: str, function: str) -> ast.Call | None:
    """The call ``module.function(...)`` of a top-level statement (bare or assigned), or None."""
    value = node.value if isinstance(node, (ast.Expr, ast.Assign)) else None
    if (
        isinstance(value, ast.Call)
        and isinstance(value.func, ast.Attribute)
        and value.func.attr == function
        and isinstance(value.func.value, ast.Name)
        and value.func.value.id == module
    ):
        return value
    return None


def test_there_are_scripts():
    assert len(SCRIPTS) >= 20


@pytest.mark.parametrize("script", SCRIPTS, ids=lambda p: p.stem)
def test_every_script_sweeps_its_temporaries_right_after_setting_up_its_log(script):
    """``log.setup(snakemake.log[0])`` then ``io.sweep_temporaries(snakemake.output)``, before
    any work: a job killed while writing leaves temporaries (``ssmobs.io.atomic_path``) that
    only the next job writing the same outputs may delete."""
    body = [n for n in ast.parse(script.read_text()).body if not isinstance(n, ast.ImportFrom)]
    body = [n for n in body if not (isinstance(n, ast.Expr) and isinstance(n.value, ast.Constant))]
    assert _is_call(body[0], "log", "setup"), f"{script.name}: the first statement sets up the log"
    sweep = _is_call(body[1], "io", "sweep_temporaries")
    assert sweep is not None, f"{script.name}: io.sweep_temporaries follows log.setup"
    assert ast.unparse(sweep.args[0]) == "snakemake.output", script.name
