"""The fixed numerical kernels (ssmobs/kernels.py): what is set, what a job checks, what keys
and pins them (issue 34)."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
import tomllib
from repo_paths import PACKAGE_DIR, REPO_DIR, WORKFLOW_DIR
from ssmobs import kernels
from ssmobs.cache_keys import CacheKeys


def state(kernel: str = "Haswell", threads: int = 1, dispatch: tuple[str, ...] = ("X86_V3",)):
    return {
        "blas": [{"api": "openblas", "version": "0.3", "kernel": kernel, "threads": threads,
                  "library": "libopenblas.so"}],
        "numpy": "2",
        "numpy_dispatch": list(dispatch),
    }  # fmt: skip


def test_the_environment_fixes_threads_everywhere_and_kernels_on_avx2_cpus(monkeypatch):
    monkeypatch.setattr(kernels, "covered", lambda: True)
    env = kernels.environment()
    assert env["OPENBLAS_CORETYPE"] == "Haswell"
    assert {"X86_V4", "AVX512_SKX", "AVX512_ICL"} <= set(env["NPY_DISABLE_CPU_FEATURES"].split())
    assert all(env[v] == "1" for v in kernels.THREAD_VARIABLES)
    monkeypatch.setattr(kernels, "covered", lambda: False)
    env = kernels.environment()
    assert "OPENBLAS_CORETYPE" not in env and "NPY_DISABLE_CPU_FEATURES" not in env
    assert all(env[v] == "1" for v in kernels.THREAD_VARIABLES)


def test_apply_sets_the_environment_a_job_inherits():
    environ: dict[str, str] = {"OPENBLAS_NUM_THREADS": "8", "OPENBLAS_CORETYPE": "SkylakeX"}
    kernels.apply(environ)
    assert environ["OPENBLAS_NUM_THREADS"] == "1"
    if kernels.covered():
        assert environ["OPENBLAS_CORETYPE"] == "Haswell"


def test_problems_name_each_departure_from_the_fixed_kernels(monkeypatch):
    monkeypatch.setattr(kernels, "covered", lambda: True)
    assert kernels.problems(state()) == []
    found = kernels.problems(state("SkylakeX", 4, ("X86_V3", "X86_V4", "AVX512_ICL")))
    assert len(found) == 3
    assert "4 threads" in found[0] and "SkylakeX" in found[1] and "X86_V4" in found[2]
    monkeypatch.setattr(kernels, "covered", lambda: False)  # only threads are fixed there
    assert kernels.problems(state("ARMV8", 1, ("ASIMD",))) == []
    assert len(kernels.problems(state("ARMV8", 2))) == 1


def test_a_process_started_with_the_environment_has_the_fixed_kernels():
    code = "from ssmobs import kernels; print(kernels.require())"
    env = {"PATH": "/usr/bin:/bin", "PYTHONPATH": str(WORKFLOW_DIR), **kernels.environment()}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert out.stdout.startswith("kernels: BLAS openblas")
    if kernels.covered():
        assert " Haswell x1" in out.stdout and "AVX512" not in out.stdout


def test_scipys_blas_is_listed_without_importing_scipy_linalg():
    """in_force loads SciPy's OpenBLAS from the wheel's folder: the same libraries, kernels
    and threads as after importing scipy.linalg, which it leaves unimported (a job's 0.35 s);
    SciPy's extensions then use the library already loaded (no second copy)."""
    code = (
        "import json, sys; from ssmobs import kernels; first = kernels.in_force(); "
        "unimported = 'scipy.linalg' not in sys.modules; import scipy.linalg; "
        "from threadpoolctl import threadpool_info; "
        "n = sum(i['user_api'] == 'blas' for i in threadpool_info()); "
        "print(json.dumps([first, kernels.in_force(), unimported, n]))"
    )
    env = {"PATH": "/usr/bin:/bin", "PYTHONPATH": str(WORKFLOW_DIR), **kernels.environment()}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    first, after_import, unimported, n_blas = json.loads(out.stdout)
    assert unimported
    assert first == after_import
    assert len(first["blas"]) == n_blas == 2  # NumPy's and SciPy's, each once
    assert any("scipy_openblas-" in blas["library"] for blas in first["blas"])


def test_a_job_started_without_it_refuses_to_compute():
    """A script run outside Snakemake, with four threads: one clear error, no numbers."""
    code = "from ssmobs import log; log.setup('/dev/null')"
    env = {"PATH": "/usr/bin:/bin", "PYTHONPATH": str(WORKFLOW_DIR),
           "OPENBLAS_NUM_THREADS": "4"}  # fmt: skip
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True)
    assert out.returncode != 0
    assert "KernelsNotFixed" in out.stderr
    assert re.search(r"runs [2-9] threads, not 1", out.stderr), out.stderr  # capped at the cores


def test_every_cache_key_holds_the_kernel_settings():
    import yaml

    config = yaml.safe_load((REPO_DIR / "config" / "smoke.yaml").read_text())
    from ssmobs.config import validation as ssmobs_config

    ssmobs_config.validate(config)
    keys = CacheKeys(config, "native stanc3 test")
    _ = keys.design
    payloads = keys.describe()
    assert payloads and all(p["kernels"] == kernels.SETTINGS_ID for p in payloads.values())


def test_every_dependency_is_pinned_to_one_version_in_the_constraints_file():
    pins = {}
    for line in (REPO_DIR / "envs" / "constraints.txt").read_text().splitlines():
        if line and not line.startswith("#"):
            name, _, version = line.partition("==")
            assert version, f"envs/constraints.txt: {line!r} is not name==version"
            pins[re.sub(r"[-_.]+", "-", name.lower())] = version
    project = tomllib.loads((REPO_DIR / "pyproject.toml").read_text())["project"]
    deps = project["dependencies"] + [d for ds in project["optional-dependencies"].values()
                                      for d in ds]  # fmt: skip
    for dep in deps:
        name = re.sub(r"[-_.]+", "-", re.split(r"[<>=!~\[; ]", dep, maxsplit=1)[0].lower())
        assert name in pins, f"{name} (pyproject.toml) is not pinned in envs/constraints.txt"


@pytest.mark.parametrize("module", ["numpy", "scipy", "threadpoolctl"])
def test_the_environment_has_the_pinned_versions(module):
    """The versions the numbers depend on are the pinned ones (make setup installs them)."""
    import importlib

    pins = dict(
        line.split("==")
        for line in (REPO_DIR / "envs" / "constraints.txt").read_text().splitlines()
        if "==" in line and not line.startswith("#")
    )
    assert importlib.import_module(module).__version__ == pins[module]


def test_a_script_restarts_itself_with_the_fixed_kernels(tmp_path):
    script = tmp_path / "script.py"
    script.write_text(
        "import os\nfrom ssmobs import kernels\nkernels.restart_with_fixed_kernels()\n"
        "print(os.environ['OPENBLAS_NUM_THREADS'], kernels.require().startswith('kernels:'))\n"
    )
    env = {"PATH": "/usr/bin:/bin", "PYTHONPATH": str(WORKFLOW_DIR),
           "OPENBLAS_NUM_THREADS": "4"}  # fmt: skip
    out = subprocess.run([sys.executable, str(script)], env=env, capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["1", "True"]


def _direct_call(env: dict[str, str]) -> subprocess.CompletedProcess:
    code = (
        "import warnings; warnings.simplefilter('always')\n"
        "from ssmobs.design.disturbances import design_disturbances\n"
        "design_disturbances(4, 6); design_disturbances(4, 6, method='random')\n"
    )
    return subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=300
    )


def test_a_direct_call_warns_once_when_the_fixed_kernels_are_not_in_force():
    """Issue 46: design_disturbances(...) in plain Python ran with the machine's kernels
    and 2 BLAS threads, silently.  Now it warns once, in one line, with the settings that
    give the workflow's numbers; with them set it says nothing."""
    base = {k: v for k, v in os.environ.items() if k not in kernels.environment()}
    base["PYTHONPATH"] = str(Path(kernels.__file__).resolve().parents[1])
    own = _direct_call({**base, "OPENBLAS_NUM_THREADS": "2"})
    assert own.returncode == 0, own.stderr[-2000:]
    said = [line for line in own.stderr.splitlines() if "KernelsWarning" in line]
    assert len(said) == 1 and "runs 2 threads, not 1" in said[0]
    assert "OPENBLAS_CORETYPE=Haswell" in said[0]
    fixed = _direct_call({**base, **kernels.environment()})
    assert fixed.returncode == 0 and "KernelsWarning" not in fixed.stderr, fixed.stderr[-2000:]


def test_the_docs_name_exactly_the_entry_points_that_warn():
    """Issue 61: the docs said "the public entry points" warn in a plain environment, while
    only design_disturbances did; joint_map() and exact_marginal() gave other bits silently.
    docs/reproducibility.md lists which warn and which do not: the list is the code's."""
    import ast

    warned = set()
    for path in sorted(PACKAGE_DIR.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if (
                isinstance(node, ast.Call)
                and getattr(node.func, "attr", None) == "warn_once_if_not_fixed"
                and node.args
                and isinstance(node.args[0], ast.Constant)
            ):
                warned.add(node.args[0].value)
    text = (REPO_DIR / "docs" / "reproducibility.md").read_text()
    said = re.search(r"^- warns: (.*?);$", text, flags=re.M | re.S)
    silent = re.search(r"^- does not warn \(.*?\):\s+(.*?)\s+and every", text, flags=re.M | re.S)
    assert said is not None and silent is not None
    assert set(re.findall(r"`([\w.]+)`", said.group(1))) == warned
    assert not set(re.findall(r"`([\w.]+)`", silent.group(1))) & warned
    assert {"ssmobs.joint_map.driver.joint_map", "ssmobs.exact.marginal.exact_marginal"} <= (
        warned | set(re.findall(r"`([\w.]+)`", silent.group(1)))
    )
