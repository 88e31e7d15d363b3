"""tests/unit is arranged like the package (issue 62): a folder of tests/unit is a subpackage
of ssmobs (its modules' tests) or repository/ (checks of the tree as a whole: docs, README,
scripts, committed outputs, the import graph); the top-level modules' tests sit in tests/unit.

The test folders hold no ``__init__.py``, so pytest imports each test module under its file
name alone: two test files with one name anywhere under tests/ could not both be imported."""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import pytest
from repo_paths import PACKAGE_DIR, TESTS_DIR

pytestmark = pytest.mark.unit

UNIT_DIR = TESTS_DIR / "unit"
#: the one folder of tests/unit that is no subpackage of ssmobs
REPOSITORY_CHECKS = "repository"


def _folders(root: Path) -> set[str]:
    return {p.name for p in root.iterdir() if p.is_dir() and p.name != "__pycache__"}


def test_every_folder_of_the_unit_tests_is_a_subpackage_or_the_repository_checks():
    subpackages = {p.parent.name for p in PACKAGE_DIR.glob("*/__init__.py")}
    stray = _folders(UNIT_DIR) - subpackages - {REPOSITORY_CHECKS}
    assert stray == set(), f"folders of tests/unit that are no subpackage of ssmobs: {stray}"


def test_no_two_test_files_share_a_file_name():
    names = Counter(
        p.name
        for p in TESTS_DIR.rglob("*.py")
        if "__pycache__" not in p.parts and p.name != "conftest.py"
    )
    assert [name for name, n in names.items() if n > 1] == []
