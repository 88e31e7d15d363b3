"""What rules sample_nuts and gather_nuts read (Sec. III.C)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from ..blocks import stan_gradients, stan_settings
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
        return prior_config_of(self.prior)

    @property
    def stan_config(self) -> dict[str, Any]:
        """The merged stan block as the config gives it (its lists as lists)."""
        return {k: plain(v) for k, v in self.stan}

    @property
    def convergence_config(self) -> dict[str, Any]:
        """The ``convergence`` block as the config gives it."""
        return {k: plain(v) for k, v in self.convergence}

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
        prior=frozen(entry.get("prior")),
        stan_init=str(entry["stan_init"]),
        stan_seed=None if stan_seed is None else int(stan_seed),
        stan=frozen(stan),
        convergence=frozen(config["convergence"]),
        threads=NUTS_THREADS,
    )
