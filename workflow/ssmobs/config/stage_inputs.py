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

from .blocks import joint_map_settings


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
