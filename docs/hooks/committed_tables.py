"""MkDocs hook: numbers of a committed run rendered from its files, never retyped.

Three markers:

- ``<!-- paper-comparison: paper_figures/<folder> -->`` becomes the table of
  :func:`ssmobs.reports.paper_comparison.paper_comparison` (every value the paper states, ours
  beside it, with its Monte Carlo standard error and z) and a sentence naming the largest
  |z|.
- ``<!-- section4-rows: paper_figures/section4_rows -->`` becomes one table of every
  committed Section IV row at the paper's iterations (one folder per row, issue 20).
- ``<!-- table-if-made: paper_figures/<folder>/<table>.md -->`` becomes that table. A folder
  made before the workflow wrote the table does not have it; the page then says so and
  names the command that writes it, instead of failing the build.
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import pandas as pd
from mkdocs.config.defaults import MkDocsConfig
from mkdocs.structure.files import Files
from mkdocs.structure.pages import Page
from ssmobs.binomial import format_fraction
from ssmobs.reports.paper_comparison import paper_comparison

COMPARISON = re.compile(r"<!-- paper-comparison: (?P<folder>[\w./-]+) -->")
ROWS = re.compile(r"<!-- section4-rows: (?P<folder>[\w./-]+) -->")
OPTIONAL_TABLE = re.compile(r"<!-- table-if-made: (?P<path>[\w./-]+\.md) -->")


def _fmt(value: float) -> str:
    return "" if value is None or not math.isfinite(value) else f"{value:.4g}"


def render_comparison(folder: Path) -> str:
    """The comparison of ``folder`` as a Markdown table with one sentence above it."""
    frame = paper_comparison(folder)
    if frame.empty:
        return "*The paper states none of this folder's values.*"
    lines = [
        "| T | quantity | K | ours | paper | RD | standard error | z |",
        "|--:|:--|--:|--:|--:|--:|--:|--:|",
    ]
    for r in frame.to_dict("records"):
        lines.append(
            f"| {r['T']} | {r['quantity']} | {r['K']} | {_fmt(r['ours'])} | {_fmt(r['paper'])} "
            f"| {_fmt(r['rel_diff'])} | {_fmt(r['standard_error'])} | {_fmt(r['z'])} |"
        )
    judged = frame.dropna(subset=["z"])
    if judged.empty:
        head = "No value here has a Monte Carlo standard error to judge it by."
    else:
        worst = judged.loc[judged["z"].abs().idxmax()]
        apart = (
            f"{worst['quantity']} at T = {worst['T']}: {abs(worst['z']):.1f} standard errors "
            f"from the paper's (RD {worst['rel_diff']:.3g})"
        )
        if len(judged) == 1:
            head = f"One value has a standard error, {apart}."
        else:
            head = (
                f"Of the {len(judged)} values with a standard error, the farthest is {apart}; "
                f"{int((judged['z'].abs() <= 2).sum())} are within two standard errors."
            )
    return head + "\n\n" + "\n".join(lines)


def render_optional_table(root: Path, path: str) -> str:
    """The committed table at ``path``, or a note that its folder was made without it."""
    table = root / path
    if table.exists():
        return table.read_text()
    if not (table.parent / "provenance.json").exists():
        folder = table.parent.relative_to(root)
        return f"*`{folder}` is not made yet: the text above names its command.*"
    prov = json.loads((table.parent / "provenance.json").read_text())
    return (
        f"*`{table.name}` is not in this folder: it was made at commit "
        f"`{prov['commit'][:12]}`, before the workflow wrote it. `{prov['command']}` writes "
        "it.*"
    )


def render_rows(folder: Path) -> str:
    """One line per committed row folder under ``folder`` (each a run of one config of
    ``config/section4_rows/``): |K^max|/K over all K, |K^Stan|/K over the Stan runs, with
    their 95 % intervals, beside the paper's, and how the row was made."""
    lines = [
        "| row | T | K | Stan runs | K^max/K | paper | K^Stan/K | paper | made |",
        "|:--|--:|--:|--:|:--|:--|:--|:--|:--|",
    ]
    for summary in sorted(folder.glob("*/section4_summary.csv")):
        prov = json.loads((summary.parent / "provenance.json").read_text())
        made = f"`{prov['commit'][:12]}`, {prov['date_utc'][:10]}"
        for r in pd.read_csv(summary).to_dict("records"):
            runs = r.get("K_stan_runs", r["K"])

            cells = [
                r["scenario"],
                r["T"],
                r["K"],
                runs,
                format_fraction(r["K_max"], r["K"]),
                format_fraction(r["K_max_paper"], r["K_paper"]),
                format_fraction(r["K_stan"], runs),
                format_fraction(r["K_stan_paper"], r["K_paper"]),
                made,
            ]
            lines.append("| " + " | ".join(str(c) for c in cells) + " |")
    if len(lines) == 2:
        return (
            "*No row is committed yet: `make section4-rows` (or one row with `make section4 "
            "SECTION4_CONFIG=config/section4_rows/<row>.yaml`) makes them.*"
        )
    return "\n".join(lines)


def on_page_markdown(markdown: str, page: Page, config: MkDocsConfig, files: Files) -> str:
    root = Path(config.config_file_path).resolve().parent
    markdown = COMPARISON.sub(lambda m: render_comparison(root / m["folder"]), markdown)
    markdown = ROWS.sub(lambda m: render_rows(root / m["folder"]), markdown)
    return OPTIONAL_TABLE.sub(lambda m: render_optional_table(root, m["path"]), markdown)
