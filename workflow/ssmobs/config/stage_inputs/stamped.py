"""Every stamped table and figure of one run (issue 62): which ones the config makes, the
files each rule reads (by input name), what it reads beside them (:mod:`.outputs`) and the
key its stamp holds, all in one record, :class:`StampedOutput`, that the rules read whole:
``input: unpack(stamped_files(name))``, ``params: inputs=stamped_inputs, key=stamp_key``
(``workflow/rules/common.smk``).

:func:`stamped_outputs` takes the run's paths (a :class:`ssmobs.run_paths.RunPaths`, which
builds the records: :attr:`~ssmobs.run_paths.RunPaths.stamped_outputs`) and the function
that keys a table or figure; it imports neither.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import Any

from .outputs import (
    FigureExactVsStanInputs,
    FigureObservabilityInputs,
    ObservabilityMapInputs,
    OutputInputs,
    Pairs,
    TableKSelectionInputs,
    convergence_sensitivity_inputs,
    figure_design_points_inputs,
    figure_joint_vs_marginal_inputs,
    figure_profile_posterior_inputs,
    freeze,
    mu0_sweep_inputs,
    observability_study_inputs,
    paper_tables_inputs,
    select_k_inputs,
    thaw,
)

#: the paper's numbers, read by the tables that print them beside ours (keyed by content)
PAPER_VALUES = "config/paper_values.yaml"

#: keys a table or figure: (its stamp's name, its files, its :meth:`OutputInputs.keyed`)
OutputKey = Callable[[str, list[str], Any], str]


@dataclass(frozen=True)
class StampedOutput:
    """One table or figure of ``outputs_dir``: the files its rule reads (input name -> one
    path or several), what it reads beside them and the key its stamp holds, which is made
    of exactly these two (with the outputs' code)."""

    files: Pairs
    inputs: OutputInputs
    key: str

    @property
    def input_files(self) -> dict[str, Any]:
        """The rule's named inputs (``unpack``): a path, or a list of paths."""
        return dict(thaw(self.files))

    @property
    def keyed_files(self) -> list[str]:
        """Every file it reads, in the order of its inputs (what its key holds)."""
        return [p for v in self.input_files.values() for p in ([v] if isinstance(v, str) else v)]


class _Table:
    """The records of one run, each keyed as it is added (a later one may hold an earlier
    one's key)."""

    def __init__(self, output_key: OutputKey) -> None:
        self.output_key = output_key
        self.records: dict[str, StampedOutput] = {}

    def add(self, name: str, files: Mapping[str, Any], inputs: OutputInputs) -> None:
        frozen_files = freeze(dict(files))
        record = StampedOutput(frozen_files, inputs, "")
        key = self.output_key(name, record.keyed_files, inputs.keyed())
        self.records[name] = StampedOutput(frozen_files, inputs, key)

    def key(self, name: str) -> str:
        return self.records[name].key


def _entries(run: Any, names: Iterable[str]) -> list[Mapping[str, Any]]:
    return [run.scenario_entry(n) for n in names]


def stamped_outputs(run: Any, output_key: OutputKey) -> dict[str, StampedOutput]:
    """Every table and figure the config of ``run`` (a RunPaths) makes, by stamp name, each
    with its files, inputs and key (``output_key``); in the order of the rule files, an
    output that reads another's files after it."""
    config, table = run.config, _Table(output_key)
    if run.paper_outputs:  # workflow/rules/joint_map.smk
        table.add(
            "table_mu0_sweep",
            {
                "trajectories": [run.trajectories(n) for n in run.mu0_scenarios],
                "paper_values": PAPER_VALUES,
            },
            mu0_sweep_inputs(_entries(run, run.mu0_scenarios), config),
        )
    for name, entry in run.k_selections.items():  # k_selection.smk
        table.add(
            f"select_k_{name}",
            {"grids": run.k_selection_grids(name), "paper_values": PAPER_VALUES},
            select_k_inputs(entry, run.scenario_entry(entry["scenario"])),
        )
    if run.k_selections or run.paper_outputs:
        keys = tuple(table.key(f"select_k_{name}") for name in run.k_selections)
        table.add(
            "table_k_selection",
            {"selections": [run.selection(name) for name in run.k_selections]},
            TableKSelectionInputs(selection_keys=keys),
        )
    if run.paper_outputs:  # outputs.smk
        table.add(
            "paper_tables",
            run.paper_tables_inputs(),
            paper_tables_inputs(
                config, run.joint_scenarios, run.stan_scenarios, run.exact_scenarios
            ),
        )
        table.add(
            "convergence_sensitivity",
            {"tables": [run.stan_table(n) for n in run.stan_scenarios]},
            convergence_sensitivity_inputs(config, run.stan_scenarios),
        )
    _add_figures(run, table)
    for name, study in run.studies.items():  # own_model.smk
        table.add(
            f"observability_study_{name}",
            run.study_inputs(name),
            observability_study_inputs(study, _entries(run, study["scenarios"]), config),
        )
    for name, entry in run.maps.items():  # observability_map.smk
        table.add(
            f"map_{name}",
            {"cells": run.map_cells_table(name)},
            ObservabilityMapInputs(entry=freeze(entry)),
        )
    return table.records


def _add_figures(run: Any, table: _Table) -> None:
    """The paper's Figures 2-4, the figure of the observability ratios and the figures of
    the exact against the Stan marginal MAP (figures.smk)."""
    config = run.config
    if run.paper_outputs:
        table.add(
            "figure_design_points",
            {"disturbances": run.figure2_disturbances()},
            figure_design_points_inputs(config, run.keys.model_code("same")),
        )
        figure3 = run.figure3_scenarios
        table.add(
            "figure_joint_vs_marginal",
            {
                "joint": [run.joint_table(n) for n in figure3],
                "marginal": [run.stan_table(n) for n in figure3],
            },
            figure_joint_vs_marginal_inputs(_entries(run, figure3)),
        )
    name = run.figure4_scenario
    if name:
        table.add(
            f"figure_profile_posterior_{name}",
            {"trajectories": run.trajectories(name)},
            figure_profile_posterior_inputs(run.scenario_entry(name), config),
        )
    if run.paper_outputs:
        table.add(
            "figure_observability",
            {"summary": f"{run.outputs_dir}/section4_summary.csv"},
            FigureObservabilityInputs(paper_tables_key=table.key("paper_tables")),
        )
    for name in run.exact_vs_stan_scenarios:
        table.add(
            f"figure_exact_vs_stan_{name}",
            run.exact_vs_stan_inputs(name),
            FigureExactVsStanInputs(scenario=freeze(run.scenario_entry(name))),
        )
