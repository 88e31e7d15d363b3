"""Make the package importable from the source tree even without `pip install -e .`, and
keep shared fixtures on one worker when the tests run in parallel."""

from __future__ import annotations

import functools
import sys
from pathlib import Path
from typing import Any

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "workflow"))


@functools.cache
def _module_scope(module: str) -> str:
    """The scheduling unit of a test module: itself, or "smoke_run" for every module that
    uses the session-wide smoke run (tests/workflow/conftest.py)."""
    path = Path(__file__).resolve().parents[1] / module
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
            return _module_scope(nodeid.split("::")[0])

    return ModuleOrSmokeRun(config, log)
