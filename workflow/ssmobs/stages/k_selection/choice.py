"""Glue of the choice of K from the grids of :mod:`ssmobs.stages.k_selection.grid` (Sec. IV.A):
rule select_k (the RD rule per method, set variant and seed, and its figure) and rule
table_k_selection (the chosen K over every entry and seed).  Stamped outputs of
``outputs_dir``: keyed by the outputs' key, so an edit here never reruns the grid.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from ... import io
from .. import PathLike

if TYPE_CHECKING:
    from ...config.scenario import Scenario


def run_select_k(
    ksel: dict,
    scenario: Scenario,
    grids: list[PathLike],
    paper_values: PathLike,
    out_json: PathLike,
    out_csv: PathLike,
    figure_paths: list[str],
) -> dict:
    """Rule select_k: the RD rule over K_grid for every method, set variant and seed
    (:func:`ssmobs.k_selection.choose_k`); the V components as CSV and the figure."""
    import pandas as pd

    from ...k_selection import choose_k
    from ...reports.figures import figure_k_convergence
    from ...reports.tables import load_paper_values

    summaries = [row for p in grids for row in io.read_json(p, required=["points"])["points"]]
    paper = load_paper_values(paper_values).get(scenario.paper_ref, {}) or {}
    long_rows, choices = choose_k(summaries, scenario.model, ksel, scenario.name, paper)
    frame = pd.DataFrame(long_rows)
    io.write_text(out_csv, frame.to_csv(index=False, float_format="%.10g"))
    chosen = pd.DataFrame(choices)
    # one line per method, set variant and seed in the figure
    figure_k_convergence(
        frame.assign(method=frame["method"] + " " + frame["sets"]),
        chosen.assign(
            K_chosen=chosen["K_chosen"].astype(float),
            method=chosen["method"] + " " + chosen["sets"],
        ),
        f"choice of K: {ksel['name']} (c1={ksel['c1']}, c2={ksel['c2']})",
        figure_paths,
    )
    io.write_json(out_json, {"choices": choices})
    return {"choices": choices}


def run_table_k_selection(
    selections: list[PathLike], paths: list[PathLike], distribution: list[PathLike]
) -> None:
    """Rule table_k_selection: chosen K per k_selection entry, method and seed (``paths``),
    and how often each K was chosen over the seeds (``distribution``)."""
    from ...reports.tables import k_selection_distribution, k_selection_table, write_table

    rows = [c for p in selections for c in io.read_json(p, required=["choices"])["choices"]]
    table = k_selection_table(rows)
    write_table(
        table,
        paths,
        "Choice of K by relative differences (Sec. IV.A): ours per method, set variant "
        "(independent sets per K_i, or nested: one seed for all K_i) and seed, beside "
        "the paper's",
    )
    write_table(
        k_selection_distribution(table),
        distribution,
        "Choice of K over seeds (Sec. IV.A): per entry, method, set variant and (c1, c2), "
        "how many of its seeds chose each K (empty K_chosen: none on the grid), beside the "
        "paper's K",
    )
