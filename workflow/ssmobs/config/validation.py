"""Config validation: the JSON schema (with defaults) plus the checks a schema cannot express.

:func:`validate` is called by the Snakefile before the DAG is built, so a bad config
stops the run with one message naming the key, the value and what is allowed, before any
expensive work and before anything is written to ``results/``.  Every scenario and every
cell of an observability map (:func:`cell_entries`) is checked by the one check of a
scenario entry, :func:`ssmobs.config.scenario.entry_problems`.

The ground floor below it, which imports nothing of the package: the schema, its messages
and :class:`ConfigError` (:mod:`ssmobs.config.schema`), the strict reading of config files
(:mod:`ssmobs.config.files`); beside it, numbers written as text and non-finite numbers
(:mod:`ssmobs.config.numbers`) and the checks of ``outputs_dir``
(:mod:`ssmobs.config.outputs_dir`).  Their names that callers take from here are imported
below.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import yaml

from ..models import MODELS, StateSpaceModel
from ..models.check_cases import x0_values
from .blocks import stan_gradients
from .files import MAX_CONFIG_VALUES, count_values
from .files import check_config_files as check_config_files
from .files import parse_config_text as parse_config_text
from .files import read_config_file as read_config_file
from .maps import MAP_CELL_KEYS, cell_entries
from .numbers import nonfinite_problems
from .numbers import text_number_problems as text_number_problems
from .outputs_dir import RESERVED_DIRS as RESERVED_DIRS
from .outputs_dir import outputs_dir_problems
from .scenario import entry_problems
from .schema import (
    MAX_REPR,
    cut_text,
    load_schema,
    schema_problems,
    short_repr,
    summarise_problems,
)
from .schema import README as README
from .schema import ConfigError as ConfigError
from .schema import short_list as short_list

#: folders directly under results/ that the workflow uses itself; no scenario may take them
#: (compared case-insensitively, for case-insensitive file systems)
RESERVED_SCENARIO_NAMES = ("shared", "k_selection", "checksums")

#: the paper's values; every non-empty ``paper_ref`` must be one of its keys
PAPER_VALUES_PATH = Path(__file__).resolve().parents[3] / "config" / "paper_values.yaml"


def _explicit_exact(config: dict) -> set[int]:
    """Indices of the scenarios that write ``exact: true`` themselves (read before the
    schema's defaults are filled in, so that a default could never count as written)."""
    scenarios = config.get("scenarios")
    if not isinstance(scenarios, list):
        return set()
    return {i for i, sc in enumerate(scenarios) if isinstance(sc, dict) and sc.get("exact") is True}


def _where(section: str, i: int, name: Any) -> str:
    return f"{section}[{i}] ({cut_text(repr(name), 60)})"


def _scenario_problems(config: dict, explicit_exact: frozenset[int] = frozenset()) -> list[str]:
    problems = _name_problems(config["scenarios"], "scenarios")
    for i, sc in enumerate(config["scenarios"]):
        where = _where("scenarios", i, sc["name"])
        if sc["name"].lower() in RESERVED_SCENARIO_NAMES:
            problems.append(
                f"{where}.name = {sc['name']!r}: reserved (results/{sc['name']}/ "
                f"holds the workflow's own files); reserved names: "
                f"{list(RESERVED_SCENARIO_NAMES)}"
            )
        problems += [f"{where}: {cut_text(p, 2 * MAX_REPR)}" for p in entry_problems(sc)]
        model = MODELS.get(sc["model"])
        if sc.get("stan") and model is not None:
            from ..stan_backends import has_stan_file

            # without stan/<model>.stan the workflow generates the program (analytic
            # gradients; ssmobs.nuts.stan_program.stan_program): not for support constraints
            # nor for PyStan, which takes no external C++
            if not has_stan_file(sc["model"]):
                from ..nuts.analytic_program import generation_problem

                problem = generation_problem(model, config["stan"]["backend"])
                if problem is not None:
                    problems.append(
                        f"{where}.stan = True: {problem}; or set stan: false for this scenario"
                    )
        if i in explicit_exact and model is not None and not model.linear_in_states:
            problems.append(
                f"{where}.exact = True: model {sc['model']!r} is not linear in the states, "
                f"so the exact marginal stage cannot run for it; allowed: exact: false, or "
                f"leaving exact out"
            )
    names = {sc["name"] for sc in config["scenarios"]}
    problems += _name_problems(config.get("k_selection", []), "k_selection")
    for i, ks in enumerate(config.get("k_selection", [])):
        where = _where("k_selection", i, ks["name"])
        if ks["scenario"] not in names:
            problems.append(
                f"{where}.scenario = {short_repr(ks['scenario'])}: no scenario of that name; "
                f"configured: {short_list(sorted(names))}"
            )
        grid = ks["K_grid"]
        if isinstance(grid, dict):  # the paper's K_i = i * step, i = 1 .. last / step
            if grid["last"] % grid["step"] or grid["last"] < 2 * grid["step"]:
                problems.append(
                    f"{where}.K_grid = {grid}: 'last' must be a multiple of 'step' "
                    f"and at least 2 * step"
                )
                continue
            grid = ks["K_grid"] = list(range(grid["step"], grid["last"] + 1, grid["step"]))
        if any(b <= a for a, b in zip(grid, grid[1:])):
            problems.append(f"{where}.K_grid = {short_repr(grid)}: must be strictly increasing")
    models = {sc["name"]: sc["model"] for sc in config["scenarios"]}
    problems += _name_problems(config.get("observability_studies", []), "observability_studies")
    for i, st in enumerate(config.get("observability_studies", [])):
        where = _where("observability_studies", i, st["name"])
        unknown = [n for n in st["scenarios"] if n not in names]
        if unknown:
            problems.append(
                f"{where}.scenarios: no scenario(s) named {short_list(unknown)}; configured: "
                f"{short_list(sorted(names))}"
            )
        elif len({models[n] for n in st["scenarios"]}) > 1:
            problems.append(
                f"{where}.scenarios = {short_repr(st['scenarios'])}: must all use one model, "
                f"got {sorted({models[n] for n in st['scenarios']})}"
            )
    return (
        problems
        + _map_problems(config)
        + _keep_draws_problems(config)
        + _figure_problems(config)
        + _paper_output_problems(config)
        + _paper_ref_problems(config)
        + _mu0_sweep_problems(config)
        + outputs_dir_problems(config)
    )


def _map_problems(config: dict) -> list[str]:
    """Every cell of every observability map is a valid scenario (its true values too)."""
    maps = config.get("observability_maps", [])
    problems = _name_problems(maps, "observability_maps")
    for i, entry in enumerate(maps):
        where = _where("observability_maps", i, entry["name"])
        own = [k for k in MAP_CELL_KEYS if k in entry["base"]]
        if own:
            problems.append(
                f"{where}.base: {short_list(own)} are set per cell (name, T and K by the map); "
                f"leave them out of base"
            )
            continue
        model = MODELS.get(entry["base"]["model"])
        if model is None:
            problems.append(
                f"{where}.base.model = {short_repr(entry['base']['model'])}: unknown model; "
                f"allowed: {sorted(MODELS)}"
            )
            continue
        if entry["vary"] not in model.param_names:
            problems.append(
                f"{where}.vary = {short_repr(entry['vary'])}: not a parameter of model "
                f"{model.slug!r}; allowed: {list(model.param_names)}"
            )
            continue
        for cell in cell_entries(entry):
            cell_problems = entry_problems(cell)
            if cell_problems:
                text = cut_text("; ".join(cell_problems), 2 * MAX_REPR)
                problems.append(f"{where}, cell {cell['name']}: {text}")
                break  # one bad cell says what is wrong with the map
    return problems


def _name_problems(entries: list[dict], section: str) -> list[str]:
    """One problem per ``name`` of a config list that an earlier entry has already (also in
    another case: names are folders and files, and case-insensitive file systems mix them
    up), and per name ending in '.' (some file systems drop it)."""
    seen: dict[str, int] = {}
    problems = []
    for i, entry in enumerate(entries):
        name = entry["name"]
        where = f"{_where(section, i, name)}.name = {short_repr(name)}"
        j = seen.get(name.lower())
        if j is not None and entries[j]["name"] == name:
            problems.append(f"{where}: used twice (also {section}[{j}]); names must be unique")
        elif j is not None:
            problems.append(
                f"{where}: differs from {section}[{j}] ({short_repr(entries[j]['name'])}) only in "
                f"case; names must differ in more than case (they name folders and files, "
                f"which case-insensitive file systems such as macOS's and Windows' mix up)"
            )
        seen.setdefault(name.lower(), i)
        if name.endswith("."):
            problems.append(
                f"{where}: ends with '.', which some file systems (Windows) drop from "
                f"folder and file names; allowed: a name ending in a letter, digit, '_' or '-'"
            )
    return problems


def _paper_ref_problems(config: dict) -> list[str]:
    """paper_ref: empty, or a key of config/paper_values.yaml (else the paper's columns
    would silently stay empty)."""
    refs = [(i, sc) for i, sc in enumerate(config["scenarios"]) if sc["paper_ref"]]
    if not refs or not PAPER_VALUES_PATH.is_file():
        return []
    known = sorted(yaml.safe_load(PAPER_VALUES_PATH.read_text()) or {})
    return [
        f"{_where('scenarios', i, sc['name'])}.paper_ref = {short_repr(sc['paper_ref'])}: no "
        f"such key in config/paper_values.yaml (the paper's columns would stay empty); "
        f"allowed: '' (none) or one of {short_list(known)}"
        for i, sc in refs
        if sc["paper_ref"] not in known
    ]


def _mu0_sweep_problems(config: dict) -> list[str]:
    """mu0_sweep.models: known model slugs (a known model no joint-MAP scenario uses only
    adds no rows, as for profiles without Sep scenarios)."""
    unknown = [m for m in config["mu0_sweep"]["models"] if m not in MODELS]
    if not unknown:
        return []
    return [
        f"mu0_sweep.models = {short_repr(config['mu0_sweep']['models'])}: unknown model(s) "
        f"{short_repr(unknown)}; the sweep takes model slugs (workflow/ssmobs/models/<slug>.py), "
        f"not scenario names, and a known model that no joint-MAP scenario uses adds no "
        f"rows; allowed: {sorted(MODELS)}"
    ]


def _keep_draws_problems(config: dict) -> list[str]:
    """stan.keep_draws: every k must be a trajectory of at least one Stan scenario."""
    stan_K = {sc["name"]: sc["K"] for sc in config["scenarios"] if sc.get("stan", True)}
    if not stan_K:
        return []
    largest = max(stan_K.values())
    beyond = [k for k in config["stan"]["keep_draws"] if k >= largest]
    if not beyond:
        return []
    return [
        f"stan.keep_draws = {short_repr(config['stan']['keep_draws'])}: "
        f"k = {short_repr(beyond)} is beyond every Stan scenario (k counts from 0, so k < K; "
        f"the largest K is {largest}); "
        f"K per Stan scenario: {short_repr(stan_K)}"
    ]


def _figure_problems(config: dict) -> list[str]:
    """Ranges that make the figures meaningful (Figure 2's |a| < 1 is in the schema)."""
    f4 = config["figure4"]
    problems = []
    for lo, hi in (("a_min", "a_max"), ("x0_min", "x0_max")):
        if not f4[lo] < f4[hi]:
            problems.append(
                f"figure4.{lo} = {f4[lo]!r}, figure4.{hi} = {f4[hi]!r}: "
                f"{lo} must be < {hi} (the grid of Figure 4 would be empty)"
            )
    return problems


def _paper_output_problems(config: dict) -> list[str]:
    """paper_outputs: every name is a scenario that can give that table or figure."""
    scenarios = {sc["name"]: sc for sc in config["scenarios"]}
    chosen = config["paper_outputs"]
    problems = []
    for key in ("tables_2_3", "figure3", "figure4"):
        value = chosen[key]
        names = [value] if isinstance(value, str) else list(value or [])
        unknown = [n for n in names if n not in scenarios]
        if unknown:
            problems.append(
                f"paper_outputs.{key}: no scenario(s) named {short_list(unknown)}; configured: "
                f"{short_list(sorted(scenarios))}"
            )
            continue
        entries = [scenarios[n] for n in names]
        if key != "figure4":
            one_stage = [sc["name"] for sc in entries if not (sc["joint_map"] and sc["stan"])]
            if one_stage:
                problems.append(
                    f"paper_outputs.{key}: scenario(s) {short_list(one_stage)} do not run both "
                    f"stages; allowed: scenarios with joint_map and stan true"
                )
        models = [MODELS.get(sc["model"]) for sc in entries]
        if key == "figure3" and entries:
            truths = {(sc["model"], repr(sc["omega"]), repr(x0_values(sc))) for sc in entries}
            if len(truths) > 1:
                problems.append(
                    f"paper_outputs.figure3 = {short_repr(names)}: must share one model, omega "
                    f"and x0 (one pair of true-value lines), got {short_repr(sorted(truths))}"
                )
            elif models[0] is not None and models[0].state_dim != 1:
                problems.append(
                    f"paper_outputs.figure3: model {entries[0]['model']!r} has "
                    f"p = {models[0].state_dim}; Figure 3 plots a scalar x0"
                )
        if key == "figure4" and entries and models[0] is not None:
            if models[0].n_params != 1 or models[0].state_dim != 1:
                problems.append(
                    f"paper_outputs.figure4 = {short_repr(value)}: model "
                    f"{entries[0]['model']!r} has {models[0].n_params} parameter(s) "
                    f"and p = {models[0].state_dim}; Figure 4's (Omega, x0) grid "
                    f"needs one parameter and p = 1"
                )
    return problems


def _own_model_problems(config: dict) -> list[str]:
    """The model's own Python check (``python -m ssmobs.model_check <slug> --no-stan``, at
    its default cases) for every model whose noise-free trajectory at a configured entry's
    true values exceeds the size bound: a wrong ``simulate`` (say two parameters swapped)
    can blow that trajectory up, and the size check would then blame the config's values.
    The model's problem is reported instead, and the size check only when the model passes
    its own check.  Other problems of the entries are left to :func:`_scenario_problems`.
    """
    entries = list(config["scenarios"])
    for entry in config.get("observability_maps", []):
        model = MODELS.get(entry["base"].get("model"))
        if model is not None and entry["vary"] in model.param_names:
            entries += cell_entries(entry)
    suspects: set[str] = set()
    for entry in entries:
        model = MODELS.get(entry.get("model"))
        if model is None or model.slug in suspects:
            continue
        omega, x0, prior = entry.get("omega"), entry.get("x0"), entry.get("prior")
        if model.check_true_values(omega, x0, prior):
            continue  # a problem of the values themselves: reported with the entry
        if model.check_true_values(omega, x0, prior, T=entry.get("T")):
            suspects.add(model.slug)
    problems = []
    for slug in sorted(suspects):
        found = _own_python_check(MODELS[slug])
        if found:
            problems.append(
                f"model {slug!r} fails its own check (python -m ssmobs.model_check {slug}), "
                f"so the size of its trajectories at the config's true values says nothing "
                f"about the config: {found}"
            )
    return problems


def _own_python_check(model: StateSpaceModel) -> str:
    """The first problem of the model check's Python stage at its default cases (the
    message ``python -m ssmobs.model_check <slug>`` prints), or ""."""
    from ..models.self_check import python_stage_problems

    found = python_stage_problems(model)
    return found[0] if found else ""


def asks_for_paper_outputs(config: Mapping[str, Any]) -> bool:
    """Whether a (validated) config asks for the paper's tables and figures: Figure 2,
    Tables II and III with Figure 3, the Section IV summary with its figure, the convergence
    tables, the table of barrier starts (mu0_sweep) and the table of the choice of K.

    It does when it names a scenario of the paper (a scenario with a ``paper_ref``) or
    chooses what the paper's tables show (``paper_outputs``).  A study of one's own model
    names neither and gets its own outputs only (its observability studies and maps, and
    the choice of K of its ``k_selection`` entries)."""
    chosen = config["paper_outputs"]
    return any(sc["paper_ref"] for sc in config["scenarios"]) or any(
        chosen[key] for key in ("tables_2_3", "figure3", "figure4")
    )


def _backend_problems(config: dict) -> list[str]:
    backend = config["stan"]["backend"]
    if backend == "pystan" and stan_gradients(config["stan"]) == "analytic":
        return [
            "stan.gradients = 'analytic': the pystan backend takes no external C++ "
            "(it keeps Stan's autodiff); allowed with pystan: 'autodiff', or choose "
            "stan.backend 'native', 'cmdstanpy' or 'auto'"
        ]
    if backend != "cmdstanpy" or not any(sc.get("stan", True) for sc in config["scenarios"]):
        return []
    from ..stan_backends import have_cmdstan

    if not have_cmdstan():
        return [
            "stan.backend = 'cmdstanpy': no CmdStan installation was found (set $CMDSTAN "
            "or install CmdStan under ~/.cmdstan); allowed without CmdStan: 'auto' or "
            "'native' or 'pystan'"
        ]
    return []


def _exact_settings_problems(config: dict[str, Any]) -> list[str]:
    """What the exact_marginal block's schema cannot say: its range is an interval."""
    lo, hi = config["exact_marginal"]["half_line_range"]
    if lo < hi:
        return []
    return [
        f"exact_marginal.half_line_range = [{lo!r}, {hi!r}]: the lower end must be below the upper"
    ]


def validate(
    config: dict[str, Any], every_problem: bool = False, config_file: str | None = None
) -> dict[str, Any]:
    """Fill schema defaults into ``config`` (in place) and check it.

    Raises :class:`ConfigError` listing every problem (key, value, what is allowed), one
    per line; problems of one kind shared by more than a few entries of a config list (50
    scenarios over the memory limit) in one line with their number and first names
    (:func:`~ssmobs.config.schema.summarise_problems`), unless ``every_problem``.  The
    header of such a message says how to get every one: the preflight with ``--all`` and
    ``config_file``.
    """
    if not isinstance(config, dict):
        raise ConfigError(
            f"invalid configuration: the top level must be a mapping with the "
            f"required key 'scenarios', got {type(config).__name__}"
        )
    if count_values(config) > MAX_CONFIG_VALUES:
        raise ConfigError(
            f"invalid configuration: more than {MAX_CONFIG_VALUES} values (YAML aliases "
            f"expanded); a config has a few hundred"
        )
    schema = load_schema()
    problems = text_number_problems(config, schema)
    explicit_exact = frozenset(_explicit_exact(config))
    problems = problems or nonfinite_problems(config) or schema_problems(config, schema)
    if not problems:
        problems = _own_model_problems(config)
    if not problems:
        problems = (
            _scenario_problems(config, explicit_exact)
            + _backend_problems(config)
            + _exact_settings_problems(config)
        )
    if not problems:
        from . import budget

        problems = budget.problems(config)
    if problems:
        raise ConfigError(_problems_message(config, problems, every_problem, config_file))
    return config


def _problems_message(
    config: dict[str, Any], problems: list[str], every_problem: bool, config_file: str | None
) -> str:
    header = "invalid configuration"
    if not every_problem:
        names = {
            section: [e.get("name") if isinstance(e, dict) else None for e in entries]
            for section, entries in config.items()
            if isinstance(entries, list)
        }
        lines = summarise_problems(problems, names)
        if len(lines) < len(problems):
            header += (
                f" ({len(problems)} problems of {len(lines)} kinds; every one: "
                f".venv/bin/python -m ssmobs.config.preflight --all {config_file or 'CONFIGFILE'})"
            )
        problems = lines
    return f"{header}:\n  - " + "\n  - ".join(problems)
