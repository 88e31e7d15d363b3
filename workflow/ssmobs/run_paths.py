"""Every path of one run of the workflow: one frozen object built from the checked config.

The workflow's outputs live under content keys (:mod:`ssmobs.cache_keys`)::

    results/shared/design_disturbances/<key>/q{q}_K{K}_{method}_seed{seed}.nc
    results/{scenario}/<stage>/<key>/...       one folder per stage and key of a scenario
    results/k_selection/{name}/<key>/...       the grids of the choice of K (Sec. IV.A)
    results/shared/k_selection_points/<key>/   its points V_{K_i}, shared by its entries
    results/observability_map/...              the observability maps' cells and tables
    results/outputs/<outputs_dir>/*.key        what made each table and figure (stamps)
    <outputs_dir>/                             the tables and figures

:class:`RunPaths` answers every "where is ..." of the rules (``workflow/rules/*.smk``) and
the list of targets of the rule ``all``; it reads no file and writes none, so the rules'
paths can be checked without Snakemake.
"""

from __future__ import annotations

import functools
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

from .cache_keys import CacheKeys
from .config.blocks import stan_gradients
from .config.scenario import Scenario
from .config.stage_inputs import DESIGN_DIR, MAP_CELLS_DIR, design_set_path
from .config.stage_inputs.stamped import StampedOutput, stamped_outputs
from .config.validation import asks_for_paper_outputs
from .stage_table import STAGES

__all__ = ["MAP_CELLS_DIR", "RunPaths"]


def _each(stem: str, exts: Iterable[str]) -> list[str]:
    """``stem.ext`` for every ext, in order."""
    return [f"{stem}.{ext}" for ext in exts]


@dataclass(frozen=True, eq=False)
class RunPaths:
    """Where every file of one run goes: the config's entries by name, the content keys of
    this config (``keys``), the Stan backend (``backend``, resolved) and ``outputs_dir``.

    Build it with :meth:`from_config`; every path is relative to the working directory.
    """

    #: the checked config (:func:`ssmobs.config.validation.validate`)
    config: Mapping[str, Any]
    #: this config's content keys
    keys: CacheKeys
    #: the concrete Stan backend (``native``, ``cmdstanpy``, ``pystan``)
    backend: str
    #: config key outputs_dir: where the tables and figures go
    outputs_dir: str
    #: the scenarios by name, in config order (a script's params carry the entry as the
    #: config holds it: :meth:`scenario_entry`)
    scenarios: Mapping[str, Scenario]
    #: the k_selection entries by name
    k_selections: Mapping[str, Mapping[str, Any]]
    #: the observability_studies entries by name
    studies: Mapping[str, Mapping[str, Any]]
    #: the observability_maps entries by name
    maps: Mapping[str, Mapping[str, Any]]
    #: the config asks for the paper's tables and figures (it names a scenario of the paper
    #: or sets paper_outputs); a study of one's own model gets its own outputs only
    paper_outputs: bool

    @classmethod
    def from_config(cls, config: Mapping[str, Any], keys: CacheKeys, backend: str) -> RunPaths:
        """The paths of a run of the checked ``config`` with its ``keys`` and ``backend``."""
        return cls(
            config=config,
            keys=keys,
            backend=backend,
            outputs_dir=config["outputs_dir"],
            scenarios={sc["name"]: Scenario.from_config(sc) for sc in config["scenarios"]},
            k_selections={ks["name"]: ks for ks in config["k_selection"]},
            studies={st["name"]: st for st in config["observability_studies"]},
            maps={m["name"]: m for m in config["observability_maps"]},
            paper_outputs=asks_for_paper_outputs(config),
        )

    def compute_every_key(self) -> dict[str, list[tuple[dict[str, Any], str]]]:
        """Compute every key of this run up front (:attr:`keys` keeps them): a cluster job
        plans only its own job and looks its key up directly.  Returns every cell of every
        observability map with its key (issue 21), by map."""
        keys = self.keys
        for name, sc in self.scenarios.items():
            keys.check_model(name)
            keys.joint_map(name)
            keys.trajectories(name)
            if sc.stan:  # a model may have no Stan program where none runs
                keys.check_model(name, stan=True)
                keys.program(sc.model.slug)
                keys.gather(name, self.batch_size(name))  # its batches, records
            for K in {sc.K, sc.exact_trajectories}:
                keys.exact(name, K)  # and the trajectories at K
        for name in self.k_selections:
            keys.k_selection_grid(name)  # and its points
        cells = {name: keys.map_cells(name) for name in self.maps}
        for name in self.maps:
            keys.map_table(name)
        return cells

    # -- the scenarios of each stage -------------------------------------------------------

    def scenario_entry(self, name: str) -> Mapping[str, Any]:
        """Scenario ``name`` as the config holds it: what a script's params carry (the
        script builds its :class:`~ssmobs.config.scenario.Scenario`)."""
        return next(sc for sc in self.config["scenarios"] if sc["name"] == name)

    @property
    def models(self) -> list[str]:
        """The models of every scenario, sorted, each once."""
        return sorted({sc.slug for sc in self.scenarios.values()})

    @property
    def joint_scenarios(self) -> list[str]:
        """The scenarios with a joint MAP stage (Sec. III.B)."""
        return [n for n, sc in self.scenarios.items() if sc.joint_map]

    @property
    def stan_scenarios(self) -> list[str]:
        """The scenarios with a NUTS stage (Sec. III.C)."""
        return [n for n, sc in self.scenarios.items() if sc.stan]

    @property
    def stan_models(self) -> list[str]:
        """The models of the scenarios with a NUTS stage, sorted, each once."""
        return sorted({sc.slug for sc in self.scenarios.values() if sc.stan})

    def stan_source(self, model: str) -> str | list[str]:
        """``stan/<model>.stan``, or no file (an empty list, for a rule's input) for a model
        whose Stan program is generated (its key holds the model's code:
        :meth:`ssmobs.cache_keys.CacheKeys.stan_program`)."""
        path = f"stan/{model}.stan"
        return path if (self.keys.repo / path).is_file() else []

    @functools.cached_property
    def stan_programs(self) -> dict[str, tuple[Any, Any]]:
        """Model -> the Stan program NUTS runs and its C++ header or None (hand-written, else
        generated: :func:`ssmobs.nuts.stan_program.planned_stan_program`), for every model of
        :attr:`stan_models`; where they lie, nothing written (the build job writes a
        generated program)."""
        from .nuts.stan_program import planned_stan_program

        return {m: planned_stan_program(m, self.stan_gradients) for m in self.stan_models}

    @property
    def stan_gradients(self) -> str:
        """The config key ``stan.gradients`` (:func:`ssmobs.config.blocks.stan_gradients`),
        for the planned programs (:attr:`stan_programs`)."""
        return stan_gradients(self.config["stan"])

    @property
    def mu0_scenarios(self) -> list[str]:
        """The joint-MAP scenarios of the models the barrier-start sweep covers."""
        models = self.config["mu0_sweep"]["models"]
        return [n for n, sc in self.scenarios.items() if sc.joint_map and sc.slug in models]

    @property
    def exact_scenarios(self) -> list[str]:
        """The scenarios whose model the exact marginal applies to (linear in the states)."""
        return [n for n, sc in self.scenarios.items() if sc.exact_applies]

    @property
    def exact_vs_stan_scenarios(self) -> list[str]:
        """The exact scenarios with a NUTS stage too (their comparison figure)."""
        return [n for n in self.exact_scenarios if self.scenarios[n].stan]

    @property
    def table_ii_scenarios(self) -> list[str]:
        """The scenarios of Tables II and III (config key paper_outputs.tables_2_3)."""
        return list(self.config["paper_outputs"]["tables_2_3"])

    @property
    def figure3_scenarios(self) -> list[str]:
        """The scenarios of Figure 3 (config key paper_outputs.figure3)."""
        return list(self.config["paper_outputs"]["figure3"])

    @property
    def figure4_scenario(self) -> str | None:
        """The scenario of Figure 4 (config key paper_outputs.figure4), if any."""
        name: str | None = self.config["paper_outputs"]["figure4"]
        return name

    def batch_size(self, name: str) -> int:
        """The trajectories of one NUTS job of scenario ``name``."""
        return self.scenarios[name].batch_size(self.config["stan"])

    # -- design (Sec. III.A) ---------------------------------------------------------------

    @property
    def design_dir(self) -> str:
        """The design sets of this config's design settings and code."""
        return DESIGN_DIR.format(key=self.keys.design)

    def disturbances(self, q: int, K: int, method: str, seed: int) -> str:
        """K design disturbances of N(0, I_q) made by ``method`` from ``seed``."""
        return design_set_path(self.keys.design, q, K, method, seed)

    def design_set(self, name: str, K: int) -> str:
        """The design set the design trajectories of scenario ``name`` at K read
        (:meth:`~ssmobs.config.stage_inputs.TrajectoriesInputs.design_set`)."""
        sc = self.scenarios[name]
        return self.inputs("trajectories", name, K=int(K)).design_set(sc.disturbance_dim)

    def figure2_disturbances(self) -> str:
        """The design set that Figure 2 draws (config block figure2)."""
        f2 = self.config["figure2"]
        return self.disturbances(2, f2["K"], "design", f2["seed"])

    def stage_paths(self, stage: str, name: str, **at: int) -> dict[str, str]:
        """The outputs of a stage with an inputs object for a scenario (name -> path), in
        its keyed folder (:data:`ssmobs.stage_table.STAGES`); ``at``: K, for a stage keyed
        per K."""
        return STAGES[stage].paths(name, getattr(self.keys, stage)(name, **at))

    def inputs(self, stage: str, name: str, **at: int) -> Any:
        """What ``stage`` reads for scenario ``name``: the rule's only param, its key's
        content (:meth:`ssmobs.cache_keys.CacheKeys.inputs`)."""
        return self.keys.inputs(stage, name, **at)

    def trajectories(self, name: str, K: int | None = None) -> str:
        """The design trajectories of a scenario at K (its own K by default)."""
        K = self.scenarios[name].K if K is None else K
        return self.stage_paths("trajectories", name, K=int(K))["trajectories"]

    def every_trajectories(self) -> list[str]:
        """The design trajectories of every scenario, at its K and at its exact stage's K."""
        return [
            self.trajectories(name, K)
            for name, sc in self.scenarios.items()
            for K in {sc.K, sc.exact_trajectories}
        ]

    def check(self, name: str, stan: bool = False) -> str:
        """The report of the model check of a scenario (Python alone, or against Stan)."""
        stage = "check_model_stan" if stan else "check_model"
        return f"results/{name}/{stage}/{self.keys.check_model(name, stan)}.json"

    # -- joint MAP (Sec. III.B) ------------------------------------------------------------

    def joint_summary(self, name: str) -> str:
        """The summary of a scenario's joint MAP stage (|K^max| and the checks)."""
        return self.stage_paths("joint_map", name)["summary"]

    def joint_table(self, name: str) -> str:
        """The joint MAP of every trajectory of a scenario, one row each."""
        return self.stage_paths("joint_map", name)["table"]

    def stan_init_inputs(self, name: str) -> dict[str, str]:
        """The joint MAP of every trajectory when the scenario's chains start there."""
        if self.scenarios[name].stan_init == "joint_map":
            return {"joint_map": self.stage_paths("joint_map", name)["theta"]}
        return {}

    # -- NUTS (Sec. III.C) -----------------------------------------------------------------

    def checked_program(self, model: str) -> list[str]:
        """What the model check evaluates, when sampling builds it too: with the native
        backend, build_stan_model's program (its marker:
        :meth:`ssmobs.cache_keys.CacheKeys.program_marker`), so the check runs the cached
        executable after the one compile (no check job compiles, none waits on another's
        build lock).  A plain input: a rebuilt program reruns its check, as it reruns the
        sampling."""
        if self.backend != "native":
            return []
        name = next(n for n, sc in self.scenarios.items() if sc.slug == model)
        return [self.keys.program_marker(name)]

    def records_dir(self, name: str) -> str:
        """The per-trajectory NUTS records of a scenario (resumable, shared by batchings)."""
        return STAGES["nuts_records"].folder_of(name, self.keys.nuts_records(name))

    def draws_dir(self, name: str) -> str:
        """The kept draws of a scenario's NUTS runs (stan.keep_draws), as rule sample_nuts
        reads them."""
        return str(self.nuts_inputs(name).draws)

    def batch_dir(self, name: str) -> str:
        """The batch tables of a scenario's NUTS stage."""
        key = self.keys.nuts_batches(name, self.batch_size(name))
        return STAGES["nuts_batches"].folder_of(name, key)

    def nuts_batches(self, name: str) -> list[str]:
        """Every batch table of a scenario's NUTS stage, in batch order."""
        ranges = self.scenarios[name].stan_batches(self.batch_size(name))
        return [f"{self.batch_dir(name)}/batch{b}.parquet" for b in range(len(ranges))]

    def nuts_inputs(self, name: str) -> Any:
        """What rule sample_nuts reads for scenario ``name`` at its batch size."""
        return self.inputs("nuts_batches", name, batch_size=self.batch_size(name))

    def gather_inputs(self, name: str) -> Any:
        """What rule gather_nuts reads for scenario ``name`` at its batch size."""
        return self.inputs("gather", name, batch_size=self.batch_size(name))

    def gather_paths(self, name: str) -> dict[str, str]:
        """The gathered NUTS results of a scenario (name -> path)."""
        return self.stage_paths("gather", name, batch_size=self.batch_size(name))

    def stan_summary(self, name: str) -> str:
        """The summary of a scenario's NUTS stage (|K^Stan| and the convergence checks)."""
        return self.gather_paths(name)["summary"]

    def stan_table(self, name: str) -> str:
        """The marginal MAP of every trajectory of a scenario's NUTS stage."""
        return self.gather_paths(name)["table"]

    # -- exact marginal --------------------------------------------------------------------

    def exact_table(self, name: str, K: int) -> str:
        """The exact marginal MAP of every trajectory of a scenario at K."""
        return self.stage_paths("exact", name, K=K)["table"]

    def exact_summary(self, name: str) -> str:
        """Summary of the exact stage at the scenario's exact_K (the one the tables show)."""
        K = self.scenarios[name].exact_trajectories
        return self.stage_paths("exact", name, K=K)["summary"]

    def exact_vs_stan_inputs(self, name: str) -> dict[str, str]:
        """The NUTS and exact marginal MAP tables of a scenario at its K (its figure)."""
        K = self.scenarios[name].K
        return {"stan": self.stan_table(name), "exact": self.exact_table(name, K)}

    # -- the choice of K (Sec. IV.A) and observability maps ---------------------------------

    def ksel_grids_dir(self, ksel: str) -> str:
        """The grid files of one k_selection entry (keyed by its points' key and the grid)."""
        key = self.keys.k_selection_grid(ksel)
        return STAGES["k_selection_grid"].folder_of(ksel, key)

    def ksel_points_dir(self, ksel: str, method: str, sets: str, seed: int | str) -> str:
        """The cached points V_{K_i} of one grid, one file per K_i, keyed without the grid
        and the entry: every k_selection entry on the same scenario finds them."""
        points = self.inputs("k_selection_grid", ksel).points
        return f"{points}/{method}_{sets}_seed{seed}"

    def k_selection_grids(self, name: str) -> list[str]:
        """Every (method, sets, seed) grid of one k_selection entry: every seed of every
        method (a design set's seed starts its optimiser, so its K is a distribution too)."""
        grids = self.inputs("k_selection_grid", name).grids
        return [f"{self.ksel_grids_dir(name)}/{file}" for file, *_ in grids]

    @staticmethod
    def selection(name: str) -> str:
        """The chosen K of one k_selection entry."""
        return f"results/k_selection/{name}/selection.json"

    def study_inputs(self, name: str) -> dict[str, list[str]]:
        """The summaries (and NUTS tables) of the scenarios of one observability study."""
        names = self.studies[name]["scenarios"]
        joint = [n for n in names if self.scenarios[n].joint_map]
        stan = [n for n in names if self.scenarios[n].stan]
        return {
            "joint": [self.joint_summary(n) for n in joint],
            "stan": [self.stan_summary(n) for n in stan],
            "stan_tables": [self.stan_table(n) for n in stan],
        }

    def map_cells_table(self, name: str) -> str:
        """The table of every cell of one observability map."""
        return f"results/observability_map/{name}/{self.keys.map_table(name)}/cells.parquet"

    def paper_tables_inputs(self) -> dict[str, Any]:
        """The summaries the paper's tables read (Tables II, III, Sec. IV), by stage."""
        return {
            "joint": [self.joint_summary(n) for n in self.joint_scenarios],
            "marginal": [self.stan_summary(n) for n in self.stan_scenarios],
            "exact": [self.exact_summary(n) for n in self.exact_scenarios],
            "paper_values": "config/paper_values.yaml",
        }

    # -- what must be verified before it is read --------------------------------------------

    def cached_outputs(self) -> list[str]:
        """Every file in ``results/`` that a job of this config writes under this config's
        keys and later jobs read (sorted): each must carry the checksum record its job wrote
        to be reused (:func:`ssmobs.io.unrecorded_files`).  The stamped tables and figures
        are added by the Snakefile for the stamps that are current."""
        out = []
        for name, sc in self.scenarios.items():
            out.append(self.check(name))
            for K in {sc.K, sc.exact_trajectories}:
                trajectories = self.trajectories(name, K)
                out += [trajectories, f"{trajectories}.sha256"]
                out.append(self.disturbances(sc.disturbance_dim, K, sc.method, sc.seed))
        for name in self.joint_scenarios:
            out += list(self.stage_paths("joint_map", name).values())
        for name in self.stan_scenarios:
            out += [self.check(name, stan=True), *self.nuts_batches(name)]
            out += [self.stan_summary(name), self.stan_table(name)]
        out += [self.keys.program_marker(name) for name in self.stan_scenarios]
        for name in self.exact_scenarios:
            sc = self.scenarios[name]
            for K in {sc.K, sc.exact_trajectories}:
                out += list(self.stage_paths("exact", name, K=K).values())
        for name in self.k_selections:
            out += self.k_selection_grids(name)
        out += [self.map_cells_table(name) for name in self.maps]
        if self.paper_outputs:
            out.append(self.figure2_disturbances())
        return sorted(set(out))

    # -- tables and figures ----------------------------------------------------------------

    @property
    def stamps_dir(self) -> str:
        """The folder of the stamps of this run's tables and figures."""
        return f"results/outputs/{self.outputs_dir}"

    @functools.cached_property
    def stamped_outputs(self) -> dict[str, StampedOutput]:
        """Every table and figure of this run by stamp name (:meth:`stamp`): the files its
        rule reads, what it reads beside them (its inputs object) and its stamp's key
        (:func:`ssmobs.config.stage_inputs.stamped.stamped_outputs`)."""

        def key(name: str, files: list[str], content: Any) -> str:
            return self.keys.output(f"{self.outputs_dir}/{name}", files, content)

        return stamped_outputs(self, key)

    def stamp(self, name: str) -> str:
        """The stamp file of a table or figure rule, ``name`` possibly a pattern with
        wildcards: it holds the key of what made the rule's files in outputs_dir."""
        return f"{self.stamps_dir}/{name}.key"

    def targets(self, stamps: Iterable[str], damaged: Iterable[str] = ()) -> list[str]:
        """Every target of the rule ``all``: each scenario's stages, the tables and figures
        of this config, ``stamps`` (the stamps of its tables and figures) and ``damaged``
        (intermediate outputs of this config found damaged, made again in this run)."""
        out = self.outputs_dir
        targets = [self.trajectories(name) for name in self.scenarios] + list(damaged)
        # every model check of this config, also where the outputs it gates exist: a config
        # is accepted or refused alike on a fresh clone and on any cache
        targets += [self.check(name) for name in self.scenarios]
        targets += [self.check(name, stan=True) for name in self.stan_scenarios]
        targets += [self.joint_summary(name) for name in self.joint_scenarios]
        targets += [self.stan_summary(name) for name in self.stan_scenarios]
        for name in self.k_selections:
            targets += _each(f"{out}/fig_k_convergence_{name}", ["pdf", "png"])
        if self.k_selections or self.paper_outputs:
            for part in ["", "_distribution"]:
                targets += _each(f"{out}/table_k_selection{part}", ["csv", "md", "tex"])
        targets += [self.exact_summary(name) for name in self.exact_scenarios]
        for name in self.exact_vs_stan_scenarios:
            targets += _each(f"{out}/fig_exact_vs_stan_{name}", ["pdf", "png"])
        for name in self.exact_vs_stan_scenarios:
            targets += _each(f"{out}/exact_vs_stan_{name}", ["csv", "md"])
        figure4 = self.figure4_scenario
        if figure4:
            targets += _each(f"{out}/fig4_profile_posterior_{figure4}", ["pdf", "png"])
        for name in self.studies:
            targets += _each(f"{out}/ours_{name}_observability", ["csv", "md", "png"])
        for name in self.maps:
            targets += _each(f"{out}/map_{name}", ["csv", "md", "png", "pdf"])
        targets += list(stamps)
        if not self.paper_outputs:
            return targets
        targets += _each(f"{out}/fig2_design_points", ["pdf", "png"])
        tables = ["table2_joint_vs_marginal", "table3_coverage", "section4_summary"]
        targets += [f"{out}/{stem}.{ext}" for ext in ["csv", "md", "tex"] for stem in tables]
        figures = ["fig3_joint_vs_marginal", "fig_observability_ratios"]
        targets += [f"{out}/{stem}.{ext}" for ext in ["pdf", "png"] for stem in figures]
        if self.mu0_scenarios:
            targets += _each(f"{out}/table_mu0_sweep", ["csv", "md", "tex"])
        if self.stan_scenarios:
            for stem in ["table_convergence_sensitivity", "table_convergence_failures"]:
                targets += _each(f"{out}/{stem}", ["csv", "md", "tex"])
        return targets
