"""The folders of the checkout the tests read, found from this file's place (tests/), so that
a test module reads the same paths at any depth of tests/unit/<subpackage>/."""

from __future__ import annotations

from pathlib import Path

#: the checkout's root (Snakefile, config/, docs/, workflow/)
REPO_DIR = Path(__file__).resolve().parents[1]
#: the folder on sys.path that holds the package
WORKFLOW_DIR = REPO_DIR / "workflow"
#: the package ssmobs
PACKAGE_DIR = WORKFLOW_DIR / "ssmobs"
#: the folder of the test suite (conftest.py, the test models, factories.py)
TESTS_DIR = REPO_DIR / "tests"
