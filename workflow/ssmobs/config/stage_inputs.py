"""What each stage reads, as one frozen object built from the scenario and the config
(issue 62): the rule passes it as its only param, ``run_<stage>(inputs, paths)`` reads
nothing else, and its content (:func:`inputs_payload`) with the stage's code is the stage's
cache key (:mod:`ssmobs.cache_keys`), so what is keyed is exactly what is read.

Each builder takes a validated scenario entry, the validated config and the paths of the
keyed files the stage reads (they carry the upstream keys); :data:`ssmobs.stage_table.STAGES`
names each stage's builder.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from .blocks import joint_map_settings, stan_gradients, stan_settings


def _frozen(value: Any) -> Any:
    """Plain config data with its mappings as sorted (key, value) pairs and lists as tuples,
    so an inputs object is immutable and compares by content."""
    if isinstance(value, Mapping):
        return tuple((str(k), _frozen(v)) for k, v in sorted(value.items()))
    if isinstance(value, (list, tuple)):
        return tuple(_frozen(v) for v in value)
    return value


def _prior_config(prior: Any) -> Any:
    """A frozen prior back as the config gives it (a mapping of variants or intervals)."""
    if isinstance(prior, tuple):
        return {k: list(v) if isinstance(v, tuple) else v for k, v in prior}
    return prior


def _plain(value: Any) -> Any:
    """A frozen value back as plain config data: (name, value) pairs as a mapping, other
    tuples as lists."""
    if isinstance(value, tuple):
        if value and all(
            isinstance(v, tuple) and len(v) == 2 and isinstance(v[0], str) for v in value
        ):
            return {k: _plain(v) for k, v in value}
        return [_plain(v) for v in value]
    return value


#: the folder of the design sets of one design key (rule design_disturbances)
DESIGN_DIR = "results/shared/design_disturbances/{key}"
#: one design set there
DESIGN_SET = DESIGN_DIR + "/q{q}_K{K}_{method}_seed{seed}.nc"


def design_set_path(design: str, q: int, K: int, method: str, seed: int) -> str:
    """The design set of q x K disturbances by ``method`` from ``seed`` under design key
    ``design``."""
    return DESIGN_SET.format(key=design, q=q, K=K, method=method, seed=seed)


def inputs_payload(inputs: Any) -> dict[str, Any]:
    """The content of an inputs object (its fields as plain data): what its key holds."""
    return {"stage_inputs": type(inputs).__name__, **dataclasses.asdict(inputs)}


@dataclass(frozen=True)
class TrajectoriesInputs:
    """Everything rule design_trajectories reads (Sec. III.A, Eq. (1)): the design sets' key
    (which with q, K, method and seed names the design set read, :meth:`design_set`), the
    scenario's name, model, true values, T, K, method and seed (written into the file)."""

    design: str
    scenario: str
    model: str
    #: the true parameters and initial state as the config gives them (frozen)
    omega: Any
    x0: Any
    T: int
    K: int
    method: str
    seed: int

    @property
    def omega_config(self) -> Any:
        """The true parameters as the config gives them (a mapping or a list)."""
        return _plain(self.omega)

    @property
    def x0_config(self) -> Any:
        """The true initial state as the config gives it (a number or a list)."""
        return _plain(self.x0)

    def design_set(self, q: int) -> str:
        """The design set of K disturbances of dimension ``q`` = (d + p) T the stage reads
        (the model gives d and p)."""
        return design_set_path(self.design, q, self.K, self.method, self.seed)


def trajectories_inputs(
    entry: Mapping[str, Any], config: Mapping[str, Any], *, design: str, K: int
) -> TrajectoriesInputs:
    """The inputs of rule design_trajectories for the scenario ``entry`` at K trajectories,
    under the design sets of key ``design``."""
    return TrajectoriesInputs(
        design=design,
        scenario=str(entry["name"]),
        model=str(entry["model"]),
        omega=_frozen(entry["omega"]),
        x0=_frozen(entry["x0"]),
        T=int(entry["T"]),
        K=int(K),
        method=str(entry["method"]),
        seed=int(entry["seed"]),
    )


@dataclass(frozen=True)
class JointMapInputs:
    """Everything rule joint_map reads (Sec. III.B): the scenario's design trajectories
    (their keyed path), the scenario's name, model, T, method and seed (written into the
    summary), its prior and its merged ``joint_map`` block
    (:func:`ssmobs.config.blocks.joint_map_settings`)."""

    trajectories: str
    scenario: str
    model: str
    T: int
    method: str
    seed: int
    #: the prior as the config gives it (a variant name, or per-parameter pairs)
    prior: Any
    #: the joint-MAP settings as sorted (key, value) pairs
    settings: tuple[tuple[str, Any], ...]

    @property
    def prior_config(self) -> Any:
        """The prior as :meth:`StateSpaceModel.prior_bounds` takes it."""
        return _prior_config(self.prior)

    @property
    def settings_config(self) -> dict[str, Any]:
        """The merged ``joint_map`` block as a mapping."""
        return dict(self.settings)


def joint_map_inputs(
    entry: Mapping[str, Any], config: Mapping[str, Any], *, trajectories: str
) -> JointMapInputs:
    """The inputs of rule joint_map for the scenario ``entry``."""
    return JointMapInputs(
        trajectories=trajectories,
        scenario=str(entry["name"]),
        model=str(entry["model"]),
        T=int(entry["T"]),
        method=str(entry["method"]),
        seed=int(entry["seed"]),
        prior=_frozen(entry.get("prior")),
        settings=_frozen(joint_map_settings(entry, config["joint_map"])),
    )


@dataclass(frozen=True)
class ExactInputs:
    """Everything rule exact_marginal reads (issue 11): a scenario's design trajectories at
    K (their keyed path), the scenario's name, its prior and the config block
    ``exact_marginal``."""

    trajectories: str
    scenario: str
    #: the prior as the config gives it (a variant name, or per-parameter pairs)
    prior: Any
    #: the ``exact_marginal`` block as sorted (key, value) pairs
    settings: tuple[tuple[str, Any], ...]

    @property
    def prior_config(self) -> Any:
        """The prior as :meth:`StateSpaceModel.prior_bounds` takes it."""
        return _prior_config(self.prior)

    @property
    def settings_config(self) -> dict[str, Any]:
        """The ``exact_marginal`` block as the config gives it (its lists as lists)."""
        return {k: list(v) if isinstance(v, tuple) else v for k, v in self.settings}


def exact_inputs(
    entry: Mapping[str, Any], config: Mapping[str, Any], *, trajectories: str
) -> ExactInputs:
    """The inputs of rule exact_marginal for the scenario ``entry`` (at the K of
    ``trajectories``)."""
    return ExactInputs(
        trajectories=trajectories,
        scenario=str(entry["name"]),
        prior=_frozen(entry.get("prior")),
        settings=_frozen(config["exact_marginal"]),
    )


@dataclass(frozen=True)
class GatherInputs:
    """Everything rule gather_nuts reads (Sec. III.C): the scenario's design trajectories,
    its batch tables and its NUTS records' folder (keyed paths), the scenario's name, K and
    ``stan_every`` (the trajectories the batches must cover), its prior (the support the
    marginal MAPs are checked against), its ``stan_init`` (written into the summary) and the
    config block ``convergence`` (the thresholds each batch is checked with)."""

    trajectories: str
    batches: tuple[str, ...]
    records: str
    scenario: str
    K: int
    stan_every: int
    #: the prior as the config gives it (a variant name, or per-parameter pairs)
    prior: Any
    stan_init: str
    #: the ``convergence`` block as sorted (key, value) pairs
    convergence: tuple[tuple[str, Any], ...]

    @property
    def prior_config(self) -> Any:
        """The prior as :meth:`StateSpaceModel.prior_bounds` takes it."""
        return _prior_config(self.prior)

    @property
    def convergence_config(self) -> dict[str, Any]:
        """The ``convergence`` block as the config gives it."""
        return {k: _plain(v) for k, v in self.convergence}

    @property
    def stan_trajectories(self) -> range:
        """The trajectories k of the Stan stage: every ``stan_every``-th of the K."""
        return range(0, self.K, self.stan_every)


def gather_inputs(
    entry: Mapping[str, Any],
    config: Mapping[str, Any],
    *,
    trajectories: str,
    batches: str,
    records: str,
    batch_size: int,
) -> GatherInputs:
    """The inputs of rule gather_nuts for the scenario ``entry`` whose batch tables of
    ``batch_size`` trajectories lie in the folder ``batches``."""
    K, every = int(entry["K"]), int(entry.get("stan_every", 1))
    n_batches = -(-len(range(0, K, every)) // int(batch_size))
    return GatherInputs(
        trajectories=trajectories,
        batches=tuple(f"{batches}/batch{b}.parquet" for b in range(n_batches)),
        records=records,
        scenario=str(entry["name"]),
        K=K,
        stan_every=every,
        prior=_frozen(entry.get("prior")),
        stan_init=str(entry["stan_init"]),
        convergence=_frozen(config["convergence"]),
    )


@dataclass(frozen=True)
class NutsBatchesInputs:
    """Everything rule sample_nuts reads (Sec. III.C) for the batches of one batch size: the
    scenario's design trajectories, its compiled program's marker (which names the backend)
    and, where its chains start there, its joint MAP (keyed paths); the folders of its NUTS
    records and kept draws (shared by batchings, named by the records' key); each batch
    table's file name with the trajectories k it holds; the scenario's name, K, seed, prior,
    chains' start and Stan seed; the stan block with the scenario's own NUTS settings over
    it (:func:`ssmobs.config.blocks.stan_settings`), the config block ``convergence`` and the
    sampler's worker processes (the rule's threads)."""

    trajectories: str
    program: str
    joint_map: str | None
    records: str
    draws: str
    #: (batch table's file name, the trajectories k it holds), in batch order
    tables: tuple[tuple[str, tuple[int, ...]], ...]
    scenario: str
    K: int
    seed: int
    #: the prior as the config gives it (a variant name, or per-parameter pairs)
    prior: Any
    stan_init: str
    stan_seed: int | None
    #: the merged stan block as sorted (key, value) pairs, its ``gradients`` set
    stan: tuple[tuple[str, Any], ...]
    #: the ``convergence`` block as sorted (key, value) pairs
    convergence: tuple[tuple[str, Any], ...]
    threads: int

    @property
    def prior_config(self) -> Any:
        """The prior as :meth:`StateSpaceModel.prior_bounds` takes it."""
        return _prior_config(self.prior)

    @property
    def stan_config(self) -> dict[str, Any]:
        """The merged stan block as the config gives it (its lists as lists)."""
        return {k: _plain(v) for k, v in self.stan}

    @property
    def convergence_config(self) -> dict[str, Any]:
        """The ``convergence`` block as the config gives it."""
        return {k: _plain(v) for k, v in self.convergence}

    def batch_of(self, table: str) -> tuple[int, ...]:
        """The trajectories k of the batch whose table is the file ``table`` (its name)."""
        return dict(self.tables)[table]


#: the worker processes of one sample_nuts job (its rule's ``threads``)
NUTS_THREADS = 1


def nuts_batches_inputs(
    entry: Mapping[str, Any],
    config: Mapping[str, Any],
    *,
    trajectories: str,
    program_marker: str,
    joint_map: str,
    records: str,
    batch_size: int,
) -> NutsBatchesInputs:
    """The inputs of rule sample_nuts for the scenario ``entry`` in batches of
    ``batch_size`` trajectories (consecutive runs of every ``stan_every``-th k);
    ``program_marker``: its compiled program's marker; ``joint_map``: the joint MAP's
    maxima, read where the chains start there."""
    K, every, size = int(entry["K"]), int(entry.get("stan_every", 1)), int(batch_size)
    ks = range(0, K, every)
    groups = [tuple(ks[i : i + size]) for i in range(0, len(ks), size)]
    stan_seed = entry.get("stan_seed")
    name = str(entry["name"])
    stan = stan_settings(entry, config["stan"])
    # the gradient path as its one reader gives it (absent: autodiff, the same inputs)
    stan["gradients"] = stan_gradients(stan)
    return NutsBatchesInputs(
        trajectories=trajectories,
        program=program_marker,
        joint_map=joint_map if entry["stan_init"] == "joint_map" else None,
        records=records,
        draws=f"results/{name}/draws/{records.rsplit('/', 1)[-1]}",
        tables=tuple((f"batch{b}.parquet", g) for b, g in enumerate(groups)),
        scenario=name,
        K=K,
        seed=int(entry["seed"]),
        prior=_frozen(entry.get("prior")),
        stan_init=str(entry["stan_init"]),
        stan_seed=None if stan_seed is None else int(stan_seed),
        stan=_frozen(stan),
        convergence=_frozen(config["convergence"]),
        threads=NUTS_THREADS,
    )


@dataclass(frozen=True)
class KSelectionGridInputs:
    """Everything rule k_selection_grid reads (Sec. IV.A) for one k_selection entry: the
    folder of its cached points V_{K_i} (keyed without the grid and the entry, so entries
    on the same scenario share them), the design sets' key and settings (the job makes its
    sets), the scenario's name (written into the grids), model, true values, T and prior,
    the merged joint-MAP settings of the paper's one start, the grid of K_i and each grid
    file's name with its method, set variant and seed."""

    points: str
    design: str
    design_settings: tuple[tuple[str, Any], ...]
    scenario: str
    model: str
    omega: Any
    x0: Any
    T: int
    prior: Any
    #: the joint-MAP settings as sorted (key, value) pairs (one start)
    settings: tuple[tuple[str, Any], ...]
    K_grid: tuple[int, ...]
    #: (grid file's name, method, set variant, seed), one per job
    grids: tuple[tuple[str, str, str, int], ...]

    @property
    def settings_config(self) -> dict[str, Any]:
        """The merged ``joint_map`` block as a mapping."""
        return dict(self.settings)

    @property
    def design_config(self) -> dict[str, Any]:
        """The ``design`` block as the config gives it."""
        return {k: _plain(v) for k, v in self.design_settings}

    @property
    def scenario_config(self) -> dict[str, Any]:
        """The scenario entry the points compute with (its K, method and seed are set per
        point)."""
        prior = _prior_config(self.prior)
        return {
            "name": self.scenario,
            "model": self.model,
            "omega": _plain(self.omega),
            "x0": _plain(self.x0),
            "T": self.T,
            "K": self.K_grid[0],
            **({} if prior is None else {"prior": prior}),
            "joint_map_start": self.settings_config["start_states"],
        }

    def grid_of(self, file: str) -> tuple[str, str, int]:
        """The method, set variant and seed of the grid written to the file ``file``."""
        return next((m, sets, seed) for f, m, sets, seed in self.grids if f == file)


def k_selection_grid_inputs(
    entry: Mapping[str, Any], config: Mapping[str, Any], *, points: str, design: str
) -> KSelectionGridInputs:
    """The inputs of rule k_selection_grid for the k_selection entry ``entry``."""
    sc = next(s for s in config["scenarios"] if s["name"] == entry["scenario"])
    return KSelectionGridInputs(
        points=points,
        design=design,
        design_settings=_frozen(config["design"]),
        scenario=str(sc["name"]),
        model=str(sc["model"]),
        omega=_frozen(sc["omega"]),
        x0=_frozen(sc["x0"]),
        T=int(sc["T"]),
        prior=_frozen(sc.get("prior")),
        settings=_frozen(joint_map_settings(sc, config["joint_map"], single_start=True)),
        K_grid=tuple(int(K) for K in entry["K_grid"]),
        grids=tuple(
            (f"{method}_{sets}_seed{seed}.json", str(method), str(sets), int(seed))
            for method in entry["methods"]
            for sets in entry["sets"]
            for seed in entry["seeds"]
        ),
    )
