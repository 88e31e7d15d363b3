"""Every committed reproduction (a ``paper_figures/`` folder with ``provenance.json``) was
made from the config file that the checkout holds now: an edit of a committed profile's
config fails here until its outputs are regenerated (``make committed CONFIG=...``)."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import pytest
import yaml
from repo_paths import REPO_DIR
from ssmobs.io import file_sha256


def _committed_provenance_files() -> list[Path]:
    """The tracked ``paper_figures/**/provenance.json`` (every one found without git)."""
    try:
        out = subprocess.run(
            ["git", "ls-files", "paper_figures"],
            cwd=REPO_DIR,
            capture_output=True,
            text=True,
            check=True,
        ).stdout.split()
    except (OSError, subprocess.CalledProcessError):
        return sorted(REPO_DIR.glob("paper_figures/**/provenance.json"))
    return sorted(REPO_DIR / p for p in out if p.endswith("/provenance.json"))


FILES = _committed_provenance_files()


def test_the_checkout_holds_committed_reproductions():
    assert len(FILES) >= 1


@pytest.mark.parametrize("path", FILES, ids=lambda p: str(p.parent.relative_to(REPO_DIR)))
def test_committed_outputs_match_their_config_file(path: Path):
    prov = json.loads(path.read_text())
    config_file = REPO_DIR / prov["config_file"]
    assert config_file.is_file(), f"{path}: its config {prov['config_file']} is gone"
    assert prov["config_sha256"] == file_sha256(config_file), (
        f"{prov['config_file']} changed after {path.parent.relative_to(REPO_DIR)} was made: "
        f"regenerate it (make committed CONFIG={prov['config_file']})"
    )
    assert prov["config"] == yaml.safe_load(config_file.read_text())
    # the folder is the one the config writes to, so no profile's run overwrites another's
    assert (REPO_DIR / prov["config"]["outputs_dir"]).resolve() == path.parent.resolve()
    assert prov["wall_seconds"] > 0 and len(prov["commit"]) == 40
    # exactly what its recorded commit produces: a clean checkout, an empty results/
    assert prov["uncommitted_changes"] is False, f"{path}: made with uncommitted changes"
    assert prov["started_from_empty_results"] is True, f"{path}: results/ was not empty"
