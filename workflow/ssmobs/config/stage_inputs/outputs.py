"""What each stamped table and figure of ``outputs_dir`` reads (issue 62): one frozen object
per output, built from the config once.

The object is its rule's only settings param (``params: inputs=stamped_inputs``) and all
its script reads beside the input and output files; its :meth:`OutputInputs.keyed` content,
with those files and the outputs' code, is the key its stamp holds
(:meth:`ssmobs.cache_keys.CacheKeys.output`), so what is keyed is exactly what is read.
Config values are kept as the config gives them, frozen (:func:`freeze`, in the config's
order) and read back unchanged (:func:`thaw`): the keyed content is the config's data
itself, as the stamps held it before the objects existed.

Which outputs a run makes, and the files each reads: :mod:`.stamped`.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any, ClassVar


class Pairs(tuple):  # type: ignore[type-arg]
    """A config mapping frozen: its (key, value) pairs in the config's order."""

    __slots__ = ()


def freeze(value: Any) -> Any:
    """Plain config data frozen: mappings as :class:`Pairs`, lists as tuples, in order."""
    if isinstance(value, Mapping):
        return Pairs((k, freeze(v)) for k, v in value.items())
    if isinstance(value, (list, tuple)):
        return tuple(freeze(v) for v in value)
    return value


def thaw(value: Any) -> Any:
    """Frozen config data back as the config gives it (``thaw(freeze(x)) == x``)."""
    if isinstance(value, Pairs):
        return {k: thaw(v) for k, v in value}
    if isinstance(value, tuple):
        return [thaw(v) for v in value]
    return value


@dataclass(frozen=True)
class OutputInputs:
    """What one stamped table or figure reads beside its files.  Its key holds every field
    as the config gives it, by field name (:meth:`keyed`); an output keyed by one value
    alone names that field in ``KEYED_AS``."""

    #: the field whose value alone is keyed, or None: every field by its name
    KEYED_AS: ClassVar[str | None] = None

    def keyed(self) -> Any:
        """The content the stamp's key holds (plain data: mappings, lists, numbers, text)."""
        if self.KEYED_AS is not None:
            return thaw(getattr(self, self.KEYED_AS))
        return {f.name: thaw(getattr(self, f.name)) for f in dataclasses.fields(self)}


@dataclass(frozen=True)
class FigureDesignPointsInputs(OutputInputs):
    """Figure 2 (Sec. III.A): the config block ``figure2`` (a, x0, K and the seed of its
    design set) and the code of model Same, whose trajectories it draws (keyed, not read)."""

    figure: Pairs
    model_code: Pairs

    @property
    def figure_config(self) -> dict[str, Any]:
        """The block ``figure2`` as the config gives it."""
        return dict(thaw(self.figure))


@dataclass(frozen=True)
class FigureJointVsMarginalInputs(OutputInputs):
    """Figure 3: the scenario entries of ``paper_outputs.figure3``."""

    KEYED_AS: ClassVar[str | None] = "scenarios"
    scenarios: tuple[Pairs, ...]

    @property
    def scenario_entries(self) -> list[dict[str, Any]]:
        """The scenario entries as the config gives them, in its order."""
        return list(thaw(self.scenarios))


@dataclass(frozen=True)
class FigureProfilePosteriorInputs(OutputInputs):
    """Figure 4 (Sec. IV.E): the scenario entry of ``paper_outputs.figure4`` and the grid
    (config block ``figure4``)."""

    scenario: Pairs
    grid: Pairs

    @property
    def scenario_entry(self) -> dict[str, Any]:
        """The scenario entry as the config gives it."""
        return dict(thaw(self.scenario))

    @property
    def grid_config(self) -> dict[str, Any]:
        """The block ``figure4`` as the config gives it."""
        return dict(thaw(self.grid))


@dataclass(frozen=True)
class FigureObservabilityInputs(OutputInputs):
    """The figure of |K^max|/K and |K^Stan|/K: it reads the Section IV summary only, which
    the paper's tables wrote, so the key of those tables stands for that file's content."""

    KEYED_AS: ClassVar[str | None] = "paper_tables_key"
    paper_tables_key: str


@dataclass(frozen=True)
class FigureExactVsStanInputs(OutputInputs):
    """The Stan + KDE against exact marginal MAP figure of one scenario: its entry."""

    KEYED_AS: ClassVar[str | None] = "scenario"
    scenario: Pairs

    @property
    def scenario_entry(self) -> dict[str, Any]:
        """The scenario entry as the config gives it."""
        return dict(thaw(self.scenario))


@dataclass(frozen=True)
class PaperTablesInputs(OutputInputs):
    """Tables II, III and the Section IV summary: every scenario entry, the scenarios of
    Tables II/III (``paper_outputs.tables_2_3``) and the names of the scenarios whose joint
    MAP, NUTS and exact summaries the rule reads, in the order of its input files."""

    scenarios: tuple[Pairs, ...]
    tables_2_3: tuple[str, ...]
    joint_names: tuple[str, ...]
    marginal_names: tuple[str, ...]
    exact_names: tuple[str, ...]

    @property
    def scenario_entries(self) -> list[dict[str, Any]]:
        """Every scenario entry as the config gives it, in its order."""
        return list(thaw(self.scenarios))


@dataclass(frozen=True)
class ConvergenceSensitivityInputs(OutputInputs):
    """The convergence tables: the NUTS scenarios' entries, in the order of their tables
    (the propriety of each posterior, Sec. IV, decides whether its |K^Stan| counts are
    shown), and the config block ``convergence``."""

    scenarios: tuple[Pairs, ...]
    convergence: Pairs

    @property
    def scenario_names(self) -> list[str]:
        """The scenarios' names, in the order of their tables."""
        return [str(dict(sc)["name"]) for sc in self.scenarios]

    @property
    def scenario_entries(self) -> dict[str, dict[str, Any]]:
        """Scenario name -> its entry as the config gives it."""
        return {str(sc["name"]): sc for sc in thaw(self.scenarios)}

    @property
    def convergence_config(self) -> dict[str, Any]:
        """The block ``convergence`` as the config gives it."""
        return dict(thaw(self.convergence))


@dataclass(frozen=True)
class SelectKInputs(OutputInputs):
    """The choice of K of one ``k_selection`` entry (Sec. IV.A): the entry and the entry of
    its scenario."""

    ksel: Pairs
    scenario: Pairs

    @property
    def ksel_entry(self) -> dict[str, Any]:
        """The ``k_selection`` entry as the config gives it."""
        return dict(thaw(self.ksel))

    @property
    def scenario_entry(self) -> dict[str, Any]:
        """Its scenario's entry as the config gives it."""
        return dict(thaw(self.scenario))


@dataclass(frozen=True)
class TableKSelectionInputs(OutputInputs):
    """The table of the choices of K: it reads the selections the choices of K wrote (not
    keyed paths), so the choices' stamp keys, in the order of the entries, stand for them."""

    KEYED_AS: ClassVar[str | None] = "selection_keys"
    selection_keys: tuple[str, ...]


@dataclass(frozen=True)
class ObservabilityMapInputs(OutputInputs):
    """The table and figure of one observability map: its ``observability_maps`` entry."""

    entry: Pairs

    @property
    def map_entry(self) -> dict[str, Any]:
        """The map's entry as the config gives it."""
        return dict(thaw(self.entry))


@dataclass(frozen=True)
class ObservabilityStudyInputs(OutputInputs):
    """One observability study: its entry, its scenarios' entries, the names of those with
    a joint MAP and with NUTS (in the order of their input files) and the config block
    ``stan`` (the caption's chains and iterations, under each scenario's own settings)."""

    study: Pairs
    scenarios: tuple[Pairs, ...]
    joint_names: tuple[str, ...]
    stan_names: tuple[str, ...]
    stan_settings: Pairs

    @property
    def study_entry(self) -> dict[str, Any]:
        """The study's entry as the config gives it."""
        return dict(thaw(self.study))

    @property
    def scenario_entries(self) -> list[dict[str, Any]]:
        """Its scenarios' entries as the config gives them, in the study's order."""
        return list(thaw(self.scenarios))

    @property
    def stan_config(self) -> dict[str, Any]:
        """The block ``stan`` as the config gives it."""
        return dict(thaw(self.stan_settings))


@dataclass(frozen=True)
class Mu0SweepInputs(OutputInputs):
    """The barrier-start sweep: its scenarios' entries (in the order of their trajectories),
    the config block ``joint_map`` and the starts ``mu0_sweep.mu0_per_T``."""

    scenarios: tuple[Pairs, ...]
    settings: Pairs
    mu0_per_T: tuple[float, ...]

    @property
    def scenario_entries(self) -> list[dict[str, Any]]:
        """Its scenarios' entries as the config gives them, in order."""
        return list(thaw(self.scenarios))

    @property
    def settings_config(self) -> dict[str, Any]:
        """The block ``joint_map`` as the config gives it."""
        return dict(thaw(self.settings))


def _names(names: Iterable[str]) -> tuple[str, ...]:
    return tuple(str(n) for n in names)


def figure_design_points_inputs(
    config: Mapping[str, Any], model_code: Mapping[str, str]
) -> FigureDesignPointsInputs:
    """Figure 2's inputs; ``model_code``: model Same's (:meth:`CacheKeys.model_code`)."""
    return FigureDesignPointsInputs(figure=freeze(config["figure2"]), model_code=freeze(model_code))


def figure_joint_vs_marginal_inputs(
    entries: Iterable[Mapping[str, Any]],
) -> FigureJointVsMarginalInputs:
    """Figure 3's inputs from the entries of its scenarios."""
    return FigureJointVsMarginalInputs(scenarios=freeze(list(entries)))


def figure_profile_posterior_inputs(
    entry: Mapping[str, Any], config: Mapping[str, Any]
) -> FigureProfilePosteriorInputs:
    """Figure 4's inputs from its scenario's entry."""
    return FigureProfilePosteriorInputs(scenario=freeze(entry), grid=freeze(config["figure4"]))


def paper_tables_inputs(
    config: Mapping[str, Any],
    joint_names: Iterable[str],
    marginal_names: Iterable[str],
    exact_names: Iterable[str],
) -> PaperTablesInputs:
    """The paper's tables' inputs; the names of the scenarios of each stage's summaries."""
    return PaperTablesInputs(
        scenarios=freeze(config["scenarios"]),
        tables_2_3=_names(config["paper_outputs"]["tables_2_3"]),
        joint_names=_names(joint_names),
        marginal_names=_names(marginal_names),
        exact_names=_names(exact_names),
    )


def convergence_sensitivity_inputs(
    config: Mapping[str, Any], stan_names: Iterable[str]
) -> ConvergenceSensitivityInputs:
    """The convergence tables' inputs for the NUTS scenarios ``stan_names``: their entries."""
    entries = {sc["name"]: sc for sc in config["scenarios"]}
    return ConvergenceSensitivityInputs(
        scenarios=freeze([entries[name] for name in _names(stan_names)]),
        convergence=freeze(config["convergence"]),
    )


def select_k_inputs(ksel: Mapping[str, Any], scenario: Mapping[str, Any]) -> SelectKInputs:
    """The choice of K's inputs from its entry and its scenario's entry."""
    return SelectKInputs(ksel=freeze(ksel), scenario=freeze(scenario))


def observability_study_inputs(
    study: Mapping[str, Any],
    entries: Iterable[Mapping[str, Any]],
    config: Mapping[str, Any],
) -> ObservabilityStudyInputs:
    """A study's inputs from its entry and its scenarios' entries, in the study's order."""
    scenarios = list(entries)
    return ObservabilityStudyInputs(
        study=freeze(study),
        scenarios=freeze(scenarios),
        joint_names=_names(sc["name"] for sc in scenarios if sc["joint_map"]),
        stan_names=_names(sc["name"] for sc in scenarios if sc["stan"]),
        stan_settings=freeze(config["stan"]),
    )


def mu0_sweep_inputs(
    entries: Iterable[Mapping[str, Any]], config: Mapping[str, Any]
) -> Mu0SweepInputs:
    """The barrier-start sweep's inputs from its scenarios' entries."""
    return Mu0SweepInputs(
        scenarios=freeze(list(entries)),
        settings=freeze(config["joint_map"]),
        mu0_per_T=freeze(config["mu0_sweep"]["mu0_per_T"]),
    )
