"""The profiles table is generated once (ssmobs.config.profiles) and shown unchanged in
README.md and config/README.md; every file of config/ has its row."""

from __future__ import annotations

from pathlib import Path

import pytest
from ssmobs.config import profiles as cp

pytestmark = pytest.mark.unit


def test_every_config_file_has_exactly_one_row():
    assert cp.undescribed() == []


@pytest.mark.parametrize("name", cp.PAGES)
def test_each_page_shows_the_generated_table(name):
    page = (cp.REPO_DIR / name).read_text()
    assert cp.table() in page, f"{name}: run {cp.COMMAND}"
    assert cp.with_table(page, name) == page


def test_a_new_config_file_without_a_row_is_reported(tmp_path: Path):
    for profile in cp.PROFILES:
        path = tmp_path / "config" / profile.pattern.replace("*", "one")
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text("{}\n")
    (tmp_path / "config" / "profiles" / "slurm").mkdir(parents=True)
    (tmp_path / "config" / "profiles" / "slurm" / "config.yaml").write_text("{}\n")
    assert cp.undescribed(tmp_path) == []
    (tmp_path / "config" / "mine.yaml").write_text("{}\n")
    assert cp.undescribed(tmp_path) == ["config/mine.yaml: matched by 0 rows ([])"]


def test_a_page_without_the_markers_is_an_error():
    with pytest.raises(ValueError, match="profiles:start"):
        cp.with_table("# a page\n", "page.md")
