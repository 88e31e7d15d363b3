"""What rules sample_nuts and gather_nuts read (Sec. III.C), and what determines the NUTS
records they share (their key)."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from ...stan_backends.base import SamplerSettings, sampler_key
from ..blocks import gradient_path, stan_settings
from .frozen import frozen, plain, prior_config_of


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
        return prior_config_of(self.prior)

    @property
    def convergence_config(self) -> dict[str, Any]:
        """The ``convergence`` block as the config gives it."""
        return {k: plain(v) for k, v in self.convergence}

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
        prior=frozen(entry.get("prior")),
        stan_init=str(entry["stan_init"]),
        convergence=frozen(config["convergence"]),
    )


#: the NUTS settings of the stan block that determine a record, in
#: :class:`~ssmobs.stan_backends.base.SamplerSettings`' order (``workers``, the job's threads,
#: schedules chains and changes no draw; ``batch_size`` and ``keep_draws`` only group them)
SAMPLER_FIELDS: tuple[str, ...] = tuple(
    f.name for f in dataclasses.fields(SamplerSettings) if f.name != "workers"
)
#: the types the sampler takes each setting in (an ``init_radius: 3`` is the run of ``3.0``)
_SAMPLER_TYPES = {k: type(v) for k, v in dataclasses.asdict(SamplerSettings()).items()}


@dataclass(frozen=True)
class NutsRecordsInputs:
    """Everything that determines the NUTS record of each trajectory of a scenario (Sec.
    III.C), the records' key: its design trajectories, its compiled program's marker (which
    names the backend and the program's key) and, where its chains start there, its joint MAP
    (keyed paths); the scenario's model, name (it enters Stan's seed), seed, prior, chains'
    start and Stan seed; the sampler settings (:data:`SAMPLER_FIELDS`, the scenario's own
    over the stan block), the gradient path NUTS takes and the implementation of the
    convergence diagnostics.  Not the thresholds of the checks: the batch tables apply them
    to the stored diagnostics."""

    trajectories: str
    program: str
    joint_map: str | None
    model: str
    scenario: str
    seed: int
    #: the prior as the config gives it (a variant name, or per-parameter pairs)
    prior: Any
    stan_init: str
    stan_seed: int | None
    #: the sampler settings as sorted (key, value) pairs, one at its default left out where
    #: :func:`~ssmobs.stan_backends.base.sampler_key` leaves it out
    sampler: tuple[tuple[str, Any], ...]
    #: ``autodiff`` or ``analytic`` (:func:`ssmobs.config.blocks.gradient_path`)
    gradients: str
    #: the convergence diagnostics' implementation (``vectorized`` or ``arviz``)
    diagnostics: str

    @property
    def prior_config(self) -> Any:
        """The prior as :meth:`StateSpaceModel.prior_bounds` takes it."""
        return prior_config_of(self.prior)


def nuts_records_inputs(
    entry: Mapping[str, Any],
    config: Mapping[str, Any],
    *,
    trajectories: str,
    program_marker: str,
    joint_map: str,
    own_program: bool,
) -> NutsRecordsInputs:
    """What determines the NUTS records of the scenario ``entry``: ``program_marker``, its
    compiled program's marker; ``joint_map``, the joint MAP's maxima, read where the chains
    start there; ``own_program``, whether the model has a hand-written ``stan/<model>.stan``
    (else its generated program is analytic whatever ``stan.gradients`` says)."""
    stan = stan_settings(entry, config["stan"])
    stan_seed = entry.get("stan_seed")
    sampler = {name: _SAMPLER_TYPES[name](stan[name]) for name in SAMPLER_FIELDS if name in stan}
    return NutsRecordsInputs(
        trajectories=trajectories,
        program=program_marker,
        joint_map=joint_map if entry["stan_init"] == "joint_map" else None,
        model=str(entry["model"]),
        scenario=str(entry["name"]),
        seed=int(entry["seed"]),
        prior=frozen(entry.get("prior")),
        stan_init=str(entry["stan_init"]),
        stan_seed=None if stan_seed is None else int(stan_seed),
        sampler=frozen(sampler_key(sampler)),
        gradients=gradient_path(stan, own_program),
        diagnostics=str(config["convergence"].get("implementation", "vectorized")),
    )


#: the folder of a scenario's kept draws, named by its records' key (stan.keep_draws)
DRAWS_DIR = "results/{scenario}/draws/{key}"


@dataclass(frozen=True)
class NutsBatchesInputs:
    """Everything rule sample_nuts reads (Sec. III.C) for the batches of one batch size: what
    determines each record (:class:`NutsRecordsInputs`, read whole, so the records' key and
    what the sampler runs with cannot differ); the folders of the NUTS records and kept draws
    (shared by batchings, named by the records' key); each batch table's file name with the
    trajectories k it holds; the scenario's K, the trajectories whose draws are kept
    (``stan.keep_draws``), the thresholds of the convergence checks (the config block
    ``convergence`` but its implementation, which is the records') and the sampler's worker
    processes (the rule's threads)."""

    record: NutsRecordsInputs
    records: str
    draws: str
    #: (batch table's file name, the trajectories k it holds), in batch order
    tables: tuple[tuple[str, tuple[int, ...]], ...]
    K: int
    keep_draws: tuple[int, ...]
    #: the ``convergence`` block but ``implementation``, as sorted (key, value) pairs
    thresholds: tuple[tuple[str, Any], ...]
    threads: int

    @property
    def convergence_config(self) -> dict[str, Any]:
        """The ``convergence`` block as the config gives it, with the records'
        implementation of the diagnostics."""
        return {
            **{k: plain(v) for k, v in self.thresholds},
            "implementation": self.record.diagnostics,
        }

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
    own_program: bool,
    records: str,
    batch_size: int,
) -> NutsBatchesInputs:
    """The inputs of rule sample_nuts for the scenario ``entry`` in batches of
    ``batch_size`` trajectories (consecutive runs of every ``stan_every``-th k), whose
    records lie in the folder ``records``; the other keywords are
    :func:`nuts_records_inputs`', which builds what determines each record."""
    record = nuts_records_inputs(
        entry,
        config,
        trajectories=trajectories,
        program_marker=program_marker,
        joint_map=joint_map,
        own_program=own_program,
    )
    K, every, size = int(entry["K"]), int(entry.get("stan_every", 1)), int(batch_size)
    ks = range(0, K, every)
    groups = [tuple(ks[i : i + size]) for i in range(0, len(ks), size)]
    stan = stan_settings(entry, config["stan"])
    thresholds = {k: v for k, v in config["convergence"].items() if k != "implementation"}
    return NutsBatchesInputs(
        record=record,
        records=records,
        draws=DRAWS_DIR.format(scenario=record.scenario, key=records.rsplit("/", 1)[-1]),
        tables=tuple((f"batch{b}.parquet", g) for b, g in enumerate(groups)),
        K=K,
        keep_draws=tuple(int(k) for k in stan.get("keep_draws", ())),
        thresholds=frozen(thresholds),
        threads=NUTS_THREADS,
    )
