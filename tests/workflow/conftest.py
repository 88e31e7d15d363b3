"""The session-wide smoke run shared by the workflow tests."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))

from helpers import SMOKE, make_workdir, snakemake  # noqa: E402


@pytest.fixture(scope="session")
def smoke_run(tmp_path_factory) -> Path:
    """The smoke workflow run once, uninterrupted, with --cores 2."""
    workdir = make_workdir(tmp_path_factory.mktemp("smoke"))
    snakemake(workdir, "--cores", "2", *SMOKE)
    return workdir
