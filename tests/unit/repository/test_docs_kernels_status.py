"""The docs' table of committed folders (docs/hooks/provenance.py): CPU and kernels per folder."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import pytest
from repo_paths import REPO_DIR

HOOK = REPO_DIR / "docs" / "hooks" / "provenance.py"


@pytest.fixture(scope="module")
def hook():
    pytest.importorskip("mkdocs")
    spec = importlib.util.spec_from_file_location("docs_provenance_hook", HOOK)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _write(root: Path, folder: str, prov: dict) -> None:
    path = root / "paper_figures" / folder / "provenance.json"
    path.parent.mkdir(parents=True)
    path.write_text(json.dumps(prov))


def test_status_table_names_each_folders_cpu_and_kernels(tmp_path: Path, hook) -> None:
    base = {"date_utc": "2026-12-04T12:00:00+00:00", "commit": "0123456789abcdef"}
    _write(tmp_path, "new", {**base, "machine": {"cpu_model": "Intel Xeon"}, "numerics": {"x": 1}})
    _write(tmp_path, "old", {**base, "machine": {"cpu_model": "AMD EPYC"}})
    _write(tmp_path, "bare", base)
    rows = hook.status_table(tmp_path).splitlines()
    assert rows[0] == "| folder | made | commit | CPU | kernels |"
    by_folder = {row.split("|")[1].strip(): row for row in rows[2:]}
    assert by_folder["`paper_figures/new`"].endswith("| Intel Xeon | fixed |")
    assert by_folder["`paper_figures/old`"].endswith("| AMD EPYC | before the fixed kernels |")
    assert by_folder["`paper_figures/bare`"].endswith("| not recorded | before the fixed kernels |")
    assert all(row.count("|") == 6 for row in rows)
