"""The docs' tables of committed runs (docs/hooks/committed_tables.py): a scenario whose
posterior is improper under its prior shows no Stan number, in words (issue 60)."""

from __future__ import annotations

import importlib.util
import json
import re
from pathlib import Path

import pandas as pd
import pytest
from repo_paths import REPO_DIR
from ssmobs.reports.propriety_notes import NOT_SHOWN_IMPROPER

HOOK = REPO_DIR / "docs" / "hooks" / "committed_tables.py"

ONLY_A = {  # (Sep, d=2, p=1) with b and c on (-1, 1): x0 drops out at c = 0, inside the prior
    "model": "sep_d2_p1",
    "omega": {"a": 0.9, "b": 0.9, "c": 0.9},
    "x0": 8,
    "T": 50,
    "K": 400,
    "prior": {"a": "restricted", "b": "unrestricted", "c": "unrestricted"},
}
ALL_RESTRICTED = {**ONLY_A, "prior": "restricted"}  # c -> 0 at an end: an edge, proper


@pytest.fixture(scope="module")
def hook():
    pytest.importorskip("mkdocs")
    spec = importlib.util.spec_from_file_location("docs_committed_tables_hook", HOOK)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _summary_row(name: str, **extra: object) -> dict:
    """A Section IV summary row: 236 of 400 passed the joint MAP's checks, 59 of the 100
    Stan runs converged; the paper's |K^Stan|/K is 0.743."""
    return {
        "scenario": name,
        "T": 50,
        "K": 400,
        "K_max": 236,
        "K_max_paper": 1833,
        "K_paper": 4000,
        "K_stan": 59,
        "K_stan_runs": 100,
        "K_stan_paper": 2972,
        "K_max_frac": 0.59,
        "K_max_frac_paper": 0.45825,
        "K_stan_frac": 0.59,
        "K_stan_frac_paper": 0.743,
        **extra,
    }


def _folder(path: Path, rows: list[dict], scenarios: list[dict] | None = None, **recorded) -> Path:
    """A committed run folder: its summary and, given ``scenarios``, a provenance whose
    config holds them (what the current analysis of the folder reads) and ``recorded``."""
    path.mkdir(parents=True)
    pd.DataFrame(rows).to_csv(path / "section4_summary.csv", index=False)
    if scenarios is not None:
        prov = {
            "commit": "0123456789abcdef" * 2,
            "date_utc": "2026-12-03T10:00:00+00:00",
            "cpu_seconds": 1234.5,
            "config": {"outputs_dir": "x", "scenarios": scenarios},
            **recorded,
        }
        (path / "provenance.json").write_text(json.dumps(prov))
    return path


def _cells(line: str) -> list[str]:
    """A Markdown table line's cells, as Markdown splits them (at bars not escaped)."""
    cells = re.split(r"(?<!\\)\|", line.strip().removeprefix("|").removesuffix("|"))
    return [cell.strip().replace("\\|", "|") for cell in cells]


def _row_of(table: str, scenario: str) -> list[str]:
    (line,) = [line for line in table.splitlines() if line.startswith(f"| {scenario} |")]
    return _cells(line)


def test_a_comparison_with_every_value_withheld_says_so_and_why(tmp_path: Path, hook) -> None:
    row = _summary_row("s", K_max_frac_paper=float("nan"))  # the paper's |K^Stan|/K only
    folder = _folder(tmp_path / "run", [row], [{"name": "s", **ONLY_A}])
    text = hook.render_comparison(folder)
    head, table = text.split("\n\n")
    assert "No value here has a Monte Carlo standard error" not in head
    assert head.startswith("Every value of ours here is withheld")
    assert "`s` (improper: x0 drops out of the likelihood at c = 0" in head
    cells = _cells(table.splitlines()[2])
    assert cells[1:5] == ["|K^Stan|/K", "100", NOT_SHOWN_IMPROPER, "0.743"]
    assert "0.59" not in table


def test_a_comparison_names_the_withheld_values_beside_the_judged(tmp_path: Path, hook) -> None:
    rows = [
        _summary_row("s", improper="improper: a reason"),  # a table's own column
        _summary_row("t", improper=""),
    ]
    head, table = hook.render_comparison(_folder(tmp_path / "run", rows)).split("\n\n")
    assert head.startswith("Of the 3 values with a standard error")  # all but s's K^Stan
    assert "1 value of ours is withheld" in head and "`s` (improper: a reason)" in head
    lines = table.splitlines()[2:]
    assert sum(NOT_SHOWN_IMPROPER in line for line in lines) == 1
    assert sum("| 0.59 |" in line for line in lines) == 3  # s's K^max, t's K^max and K^Stan


def test_rows_table_withholds_an_improper_rows_k_stan(tmp_path: Path, hook) -> None:
    root = tmp_path / "section4_rows"
    _folder(root / "only_a", [_summary_row("only_a")], [{"name": "only_a", **ONLY_A}])
    _folder(root / "abc", [_summary_row("abc")], [{"name": "abc", **ALL_RESTRICTED}])
    text = hook.render_rows(root)
    only_a, abc = _row_of(text, "only_a"), _row_of(text, "abc")
    assert only_a[6] == NOT_SHOWN_IMPROPER and abc[6] == "0.59 [0.49, 0.69]"
    assert only_a[4] == abc[4] == "0.59 [0.54, 0.64]"  # K^max/K: the joint MAP's, kept
    assert only_a[7] == abc[7] == "0.74 [0.73, 0.76]"  # the paper's stays
    assert "`only_a` (improper: x0 drops out of the likelihood at c = 0" in text
    assert "`abc` (" not in text


def test_rows_table_says_which_gradient_path_made_each_row(tmp_path: Path, hook) -> None:
    """Issue 63: a row made before ``stan.gradients`` existed sampled with autodiff; a newer
    one records its path; the table names it with the row's commit and CPU time."""
    root = tmp_path / "section4_rows"
    _folder(root / "old", [_summary_row("old")], [{"name": "old", **ALL_RESTRICTED}])
    _folder(
        root / "new",
        [_summary_row("new")],
        [{"name": "new", **ALL_RESTRICTED}],
        stan={"gradients": "analytic"},
    )
    text = hook.render_rows(root)
    assert _row_of(text, "old")[8] == "`0123456789ab`, 2026-12-03, autodiff, 1,234 CPU-s"
    assert _row_of(text, "new")[8] == "`0123456789ab`, 2026-12-03, analytic, 1,234 CPU-s"


COMMITTED_ROWS = REPO_DIR / "paper_figures" / "section4_rows"


@pytest.mark.skipif(
    not (COMMITTED_ROWS / "sep_b_T75" / "provenance.json").is_file()
    or not (COMMITTED_ROWS / "sep_d1_p2_T50" / "provenance.json").is_file(),
    reason="no committed Section IV rows in this checkout",
)
def test_site_shows_no_k_stan_of_the_committed_improper_rows(hook) -> None:
    """sep_b_T75 (a = 0 inside (-1, 1)) and sep_d1_p2_T50 (c = d inside (0, 1)^4) are
    improper (sep_d1_p2_T50's folder, made before the analysis, holds |K^Stan|/K 0.00); the
    site writes the words instead."""
    text = hook.render_rows(COMMITTED_ROWS)
    for scenario in ("sep_b_T75", "sep_d1_p2_T50"):
        assert _row_of(text, scenario)[6] == NOT_SHOWN_IMPROPER
        assert f"`{scenario}` (improper: " in text
    assert _row_of(text, "sep_ab_T75")[6] != NOT_SHOWN_IMPROPER  # both restricted: proper


@pytest.fixture(scope="module")
def provenance_hook():
    pytest.importorskip("mkdocs")
    path = REPO_DIR / "docs" / "hooks" / "provenance.py"
    spec = importlib.util.spec_from_file_location("docs_provenance_hook", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize(
    ("prov", "shown"),
    [
        ({"stan": {"gradients": "analytic"}}, "`analytic`"),
        ({"stan": {}, "config": {"stan": {"gradients": "analytic"}}}, "`analytic`"),
        ({"stan": {}, "config": {}}, "`autodiff`"),  # made before the key was recorded
    ],
)
def test_provenance_names_the_gradient_path(provenance_hook, prov, shown):
    """Each committed folder's page says which gradient path made its draws (issue 63)."""
    assert provenance_hook.gradients(prov) == shown
