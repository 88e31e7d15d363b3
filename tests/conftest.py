"""Make the package importable from the source tree even without `pip install -e .`, and
keep shared fixtures on one worker when the tests run in parallel."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "workflow"))


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """With ``-n N --dist loadgroup`` (``make test``): one worker per test module, and one
    worker for every test of the session-wide smoke run, so that no module- or session-scoped
    fixture (a smoke run, a fresh compile) is computed twice."""
    if not config.getoption("dist", "no") == "loadgroup":
        return
    for item in items:
        if item.get_closest_marker("xdist_group"):
            continue
        uses_smoke = "smoke_run" in getattr(item, "fixturenames", ())
        group = "smoke_run" if uses_smoke else item.nodeid.split("::")[0]
        item.add_marker(pytest.mark.xdist_group(group))
