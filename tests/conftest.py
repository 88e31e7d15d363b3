"""Make the package importable from the source tree even without `pip install -e .`, and
keep shared fixtures on one worker when the tests run in parallel."""

from __future__ import annotations

import functools
import sys
from typing import Any

import pytest
from repo_paths import REPO_DIR, WORKFLOW_DIR

sys.path.insert(0, str(WORKFLOW_DIR))


#: the scheduling units of `make test` and `make test-slow` that take longest, longest first
#: (BENCHMARKS.md, "make test in five minutes"): each worker starts with one of them, and the
#: many short modules fill the gaps; xdist's own order (most tests first) started them last.
LONGEST_FIRST = (
    # the mutation suite (`make test-slow` only), in two units: its 14 edit cases, the rest
    "tests/workflow/test_incremental.py::test_an_edit_reruns_what_it_touches_and_equals_a_fresh_run",
    "tests/workflow/test_incremental.py",
    "smoke_run",
    "tests/workflow/test_same_bytes_on_any_kernels.py",
    "tests/workflow/test_incremental_quick.py",
    "tests/stan/test_analytic_gradients.py",
    "tests/workflow/test_own_model.py",
)


#: tests that form a scheduling unit of their own, apart from the rest of their module; each
#: worker computes the module-scoped fixtures it needs for itself (here the mutation suite's
#: baseline: one run of its tiny config, against the 14 edit cases' two runs each)
OWN_UNIT = (
    "tests/workflow/test_incremental.py::test_an_edit_reruns_what_it_touches_and_equals_a_fresh_run",
)


def _scope(nodeid: str) -> str:
    """The scheduling unit of a test: its entry in OWN_UNIT, else its module's unit."""
    function = nodeid.split("[")[0]
    if function in OWN_UNIT:
        return function
    return _module_scope(nodeid.split("::")[0])


@functools.cache
def _module_scope(module: str) -> str:
    """The scheduling unit of a test module: itself, or "smoke_run" for every module that
    uses the session-wide smoke run (tests/workflow/conftest.py)."""
    path = REPO_DIR / module
    if path.is_file() and "smoke_run" in path.read_text():
        return "smoke_run"
    return module


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_make_scheduler(config: pytest.Config, log: Any) -> Any:
    """With ``-n N --dist loadscope`` (``make test``): whole test modules go to one worker
    each, and all modules of the smoke run to the same one, so that no module- or
    session-scoped fixture (a smoke run, a fresh compile) is computed twice."""
    if config.getvalue("dist") != "loadscope":
        return None
    from xdist.scheduler import LoadScopeScheduling

    class ModuleOrSmokeRun(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            return _scope(nodeid)

        def _assign_work_unit(self, node: Any) -> None:
            # the longest units first, so that none of them starts last and runs alone
            for scope in reversed(LONGEST_FIRST):
                if scope in self.workqueue:
                    self.workqueue.move_to_end(scope, last=False)
            super()._assign_work_unit(node)

    return ModuleOrSmokeRun(config, log)
