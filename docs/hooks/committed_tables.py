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
from ssmobs.config.blocks import stan_gradients
from ssmobs.reports.paper_comparison import improper_scenarios, paper_comparison
from ssmobs.reports.propriety_notes import NOT_SHOWN_IMPROPER

COMPARISON = re.compile(r"<!-- paper-comparison: (?P<folder>[\w./-]+) -->")
ROWS = re.compile(r"<!-- section4-rows: (?P<folder>[\w./-]+) -->")
OPTIONAL_TABLE = re.compile(r"<!-- table-if-made: (?P<path>[\w./-]+\.md) -->")


def _fmt(value: float) -> str:
    return "" if value is None or not math.isfinite(value) else f"{value:.4g}"


def _cell(text: str) -> str:
    """``text`` in a Markdown table cell: its bars (|K^Stan|/K) escaped, not column breaks."""
    return text.replace("|", "\\|")


def _reasons(reasons: dict[str, str]) -> str:
    """ "`scenario` (<reason>); ..." for the scenarios whose Stan numbers are withheld."""
    return "; ".join(f"`{scenario}` ({why})" for scenario, why in sorted(reasons.items()))


#: why a table withholds a Stan number (:mod:`ssmobs.reports.propriety_notes`)
WHY_WITHHELD = "a Stan number of a posterior that may be improper under its prior estimates nothing"


def _withheld_sentence(withheld: pd.DataFrame, every: bool) -> str:
    """Which values of ours the comparison does not show, and why (|K^Stan|, marginal MAP
    and coverage rows of scenarios whose posterior is improper or undecided)."""
    n = len(withheld)
    which = "Every value of ours here is" if every else f"{n} value{'s' * (n > 1)} of ours"
    which += "" if every else (" are" if n > 1 else " is")
    why = _reasons(dict(zip(withheld["scenario"], withheld["improper"], strict=True)))
    tail = " The paper's values stay beside them." if every else ""
    return f"{which} withheld (`{NOT_SHOWN_IMPROPER}`), as {WHY_WITHHELD}: {why}.{tail}"


def _judged_sentence(judged: pd.DataFrame) -> str:
    """The value farthest from the paper's in standard errors, among those that have one."""
    if judged.empty:
        return "No value here has a Monte Carlo standard error to judge it by."
    worst = judged.loc[judged["z"].abs().idxmax()]
    apart = (
        f"{worst['quantity']} at T = {worst['T']}: {abs(worst['z']):.1f} standard errors "
        f"from the paper's (RD {worst['rel_diff']:.3g})"
    )
    if len(judged) == 1:
        return f"One value has a standard error, {apart}."
    return (
        f"Of the {len(judged)} values with a standard error, the farthest is {apart}; "
        f"{int((judged['z'].abs() <= 2).sum())} are within two standard errors."
    )


def render_comparison(folder: Path) -> str:
    """The comparison of ``folder`` as a Markdown table, with the sentences above it: the
    value farthest from the paper's, and which values are withheld as improper and why (an
    improper scenario's "ours" cell says :data:`NOT_SHOWN_IMPROPER`)."""
    frame = paper_comparison(folder)
    if frame.empty:
        return "*The paper states none of this folder's values.*"
    improper = frame["improper"].fillna("").astype(str) != ""
    lines = [
        "| T | quantity | K | ours | paper | RD | standard error | z |",
        "|--:|:--|--:|--:|--:|--:|--:|--:|",
    ]
    for r, withheld in zip(frame.to_dict("records"), improper, strict=True):
        ours = NOT_SHOWN_IMPROPER if withheld else _fmt(r["ours"])
        lines.append(
            f"| {r['T']} | {_cell(r['quantity'])} | {r['K']} | {ours} | {_fmt(r['paper'])} "
            f"| {_fmt(r['rel_diff'])} | {_fmt(r['standard_error'])} | {_fmt(r['z'])} |"
        )
    if improper.all():
        head = _withheld_sentence(frame, every=True)
    else:
        head = _judged_sentence(frame[~improper].dropna(subset=["z"]))
        if improper.any():
            head += " " + _withheld_sentence(frame[improper], every=False)
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


def made_with(prov: dict) -> str:
    """The gradient path a committed run's NUTS took, from its ``provenance.json``: the
    recorded ``stan.gradients``, else its config's key (``autodiff`` where unset: a folder
    made before the setting existed sampled with Stan's autodiff)."""
    recorded = prov.get("stan", {}).get("gradients")
    return str(recorded or stan_gradients(prov["config"].get("stan", {})))


def render_rows(folder: Path) -> str:
    """One line per committed row folder under ``folder`` (each a run of one config of
    ``config/section4_rows/``): |K^max|/K over all K, |K^Stan|/K over the Stan runs, with
    their 95 % intervals, beside the paper's, and how the row was made (commit, date,
    gradient path, CPU-s: :func:`made_with`).  A row whose
    posterior is improper under its prior (the current analysis of the scenarios in the
    folder's ``provenance.json``, or the summary's own ``improper`` column:
    :func:`~ssmobs.reports.paper_comparison.improper_scenarios`) shows
    :data:`NOT_SHOWN_IMPROPER` for |K^Stan|/K, whatever its commit wrote, and the reason
    below the table."""
    lines = [
        "| row | T | K | Stan runs | K^max/K | paper | K^Stan/K | paper | made |",
        "|:--|--:|--:|--:|:--|:--|:--|:--|:--|",
    ]
    withheld: dict[str, str] = {}
    for summary in sorted(folder.glob("*/section4_summary.csv")):
        prov = json.loads((summary.parent / "provenance.json").read_text())
        made = (
            f"`{prov['commit'][:12]}`, {prov['date_utc'][:10]}, {made_with(prov)}, "
            f"{prov['cpu_seconds']:,.0f} CPU-s"
        )
        frame = pd.read_csv(summary)
        improper = improper_scenarios(summary.parent, [frame])
        for r in frame.to_dict("records"):
            runs = r.get("K_stan_runs", r["K"])
            why = improper.get(r["scenario"], "")
            if why:
                withheld[r["scenario"]] = why
            cells = [
                r["scenario"],
                r["T"],
                r["K"],
                runs,
                format_fraction(r["K_max"], r["K"]),
                format_fraction(r["K_max_paper"], r["K_paper"]),
                NOT_SHOWN_IMPROPER if why else format_fraction(r["K_stan"], runs),
                format_fraction(r["K_stan_paper"], r["K_paper"]),
                made,
            ]
            lines.append("| " + " | ".join(str(c) for c in cells) + " |")
    if len(lines) == 2:
        return (
            "*No row is committed yet: `make section4-rows` (or one row with `make section4 "
            "SECTION4_CONFIG=config/section4_rows/<row>.yaml`) makes them.*"
        )
    if withheld:
        lines += [
            "",
            f"*|K^Stan|/K is withheld (`{NOT_SHOWN_IMPROPER}`) where the current analysis of "
            f"the scenario in the folder's provenance finds the posterior improper, as "
            f"{WHY_WITHHELD}; the folder keeps the number its commit wrote: "
            f"{_reasons(withheld)}.*",
        ]
    return "\n".join(lines)


def on_page_markdown(markdown: str, page: Page, config: MkDocsConfig, files: Files) -> str:
    root = Path(config.config_file_path).resolve().parent
    markdown = COMPARISON.sub(lambda m: render_comparison(root / m["folder"]), markdown)
    markdown = ROWS.sub(lambda m: render_rows(root / m["folder"]), markdown)
    return OPTIONAL_TABLE.sub(lambda m: render_optional_table(root, m["path"]), markdown)
