"""The configuration reference page is generated from the schema and names every key."""

from __future__ import annotations

import re
from typing import Any

import pytest
from ssmobs.config import reference as ref
from ssmobs.config.validation import load_schema

pytestmark = pytest.mark.unit


def every_key(schema: dict[str, Any], path: str = "") -> dict[str, dict[str, Any]]:
    """Every key of the schema by its path (``a.b``, ``a[].b``), walked independently of the
    module under test: properties, list entries and ``oneOf`` branches."""
    found: dict[str, dict[str, Any]] = {}
    for name, sub in schema.get("properties", {}).items():
        key = f"{path}.{name}" if path else name
        found[key] = sub
        found |= every_key(sub, key)
    if isinstance(schema.get("items"), dict):
        found |= every_key(schema["items"], f"{path}[]")
    for branch in schema.get("oneOf", []):
        found |= every_key(branch, path)
    return found


PAGE = ref.PAGE_PATH.read_text()
KEYS = every_key(load_schema())


def row(path: str) -> str:
    """The table row of the key ``path`` on the committed page."""
    rows = re.findall(rf"^\| `{re.escape(path)}` \|.*$", PAGE, flags=re.M)
    assert len(rows) == 1, f"{path}: {len(rows)} rows on the page"
    return rows[0]


def test_committed_page_is_generated_from_the_schema():
    assert PAGE == ref.render(load_schema()), (
        "docs/reference/configuration.md is not what the schema gives: "
        "run `python -m ssmobs.config.reference`"
    )


def test_every_schema_key_has_one_row_with_its_default_and_description():
    assert len(KEYS) > 80
    assert set(ref.schema_paths(load_schema())) == set(KEYS)
    for path, sub in KEYS.items():
        cells = row(path).split(" | ")
        assert len(cells) == 5, path
        if "default" in sub:
            assert cells[2] != "–", path
        assert sub.get("description"), f"{path}: the schema gives no description"
        assert cells[4].rstrip(" |") != "–", path


def test_rows_show_types_ranges_and_choices():
    assert row("scenarios[].T").startswith("| `scenarios[].T` | integer | required | ≥ 1 |")
    assert "| `0.8` | > 0, &lt; 1 |" in row("stan.adapt_delta")
    assert 'one of `random`, `"true"`' in row("scenarios[].stan_init")
    assert "| `[sep, sep_d2_p1]` |" in row("mu0_sweep.models")
    assert "integer or null" in row("scenarios[].exact_K")
    assert "\\|K^max\\|/K" in row("k_selection[].c1")  # pipes escaped inside the table
    for path, sub in KEYS.items():
        for choice in sub.get("enum", []):
            assert f"`{choice}`" in row(path) or f'`"{choice}"`' in row(path), (path, choice)


def test_check_flag_reports_a_stale_page(tmp_path, capsys):
    page = tmp_path / "configuration.md"
    assert ref.main(["--check", "--output", str(page)]) == 1
    assert ref.main(["--output", str(page)]) == 0
    assert ref.main(["--check", "--output", str(page)]) == 0
    stale = page.read_text().replace("| `stan.chains` | integer |", "| `stan.chains` | x |")
    page.write_text(stale)
    assert ref.main(["--check", "--output", str(page)]) == 1
    assert "python -m ssmobs.config.reference" in capsys.readouterr().out
