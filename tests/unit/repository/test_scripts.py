"""The rule scripts (workflow/scripts/*.py) share one set-up, :func:`ssmobs.log.start_job`:
logging (with the check of the fixed kernels), then the sweep of the temporaries an
interrupted earlier job left beside the outputs."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest
from repo_paths import REPO_DIR, WORKFLOW_DIR
from ssmobs import kernels

pytestmark = pytest.mark.unit
SCRIPTS = sorted((REPO_DIR / "workflow" / "scripts").glob("*.py"))

#: a rule script's first line, run on its own with a job of one output
START = """
import sys
from types import SimpleNamespace
from ssmobs import log
log.start_job(SimpleNamespace(log=[sys.argv[1]], output=[sys.argv[2]]))
"""


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
def test_every_script_starts_its_job_first(script):
    """``log.start_job(snakemake)`` before any work: a job killed while writing leaves
    temporaries (``ssmobs.io.atomic_path``) that only the next job writing the same outputs
    may delete, and no number is computed before the kernels are checked."""
    body = [n for n in ast.parse(script.read_text()).body if not isinstance(n, ast.ImportFrom)]
    body = [n for n in body if not (isinstance(n, ast.Expr) and isinstance(n.value, ast.Constant))]
    start = _is_call(body[0], "log", "start_job")
    assert start is not None, f"{script.name}: the first statement is log.start_job(...)"
    assert [ast.unparse(a) for a in start.args] == ["snakemake"], script.name
    assert not any(_is_call(n, "log", "setup") for n in body), f"{script.name}: set up twice"


def _start(tmp_path: Path, env: dict[str, str]) -> tuple[subprocess.CompletedProcess, Path]:
    """Run :data:`START` for the output ``out.csv`` beside a temporary a killed writer left."""
    leftover = tmp_path / ".out.csv.abcdEFGH.csv"
    leftover.write_text("half written")
    args = [str(tmp_path / "job.log"), str(tmp_path / "out.csv")]
    env = {"PATH": "/usr/bin:/bin", "PYTHONPATH": str(WORKFLOW_DIR), **env}
    out = subprocess.run(
        [sys.executable, "-c", START, *args], env=env, capture_output=True, text=True
    )
    return out, leftover


def test_a_job_start_logs_the_kernels_and_sweeps_the_leftovers(tmp_path):
    out, leftover = _start(tmp_path, kernels.environment())
    assert out.returncode == 0, out.stderr
    assert not leftover.exists()
    text = (tmp_path / "job.log").read_text()
    assert "kernels: BLAS" in text and f"removed the temporary {leftover}" in text


def test_a_job_start_without_the_fixed_kernels_stops_before_the_sweep(tmp_path):
    out, leftover = _start(tmp_path, {"OPENBLAS_NUM_THREADS": "4"})
    assert out.returncode != 0 and "KernelsNotFixed" in out.stderr
    assert leftover.exists()


def test_scripts_read_their_params_not_the_config():
    """What a script reads is what its rule passes (and its key holds): a script reading
    ``snakemake.config`` reads settings its stage's key may leave out (issue 62)."""
    reading = {
        s.stem
        for s in SCRIPTS
        for node in ast.walk(ast.parse(s.read_text()))
        if isinstance(node, ast.Attribute)
        and node.attr == "config"
        and isinstance(node.value, ast.Name)
        and node.value.id == "snakemake"
    }
    assert reading == set()
