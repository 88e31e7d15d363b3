"""One scenario of Section IV as a typed, frozen object, built once from its config entry.

The config (``config/*.yaml``, validated by :mod:`ssmobs.config.validation`) holds a scenario as
plain
data: Omega as a mapping ``{name: value}``, x0 as a number or a list, optional keys with
the schema's defaults.  Snakemake passes that plain entry to a script; the script turns it
into a :class:`Scenario` with :meth:`Scenario.from_config` at its first line, and
everything below works on the Scenario: Omega as an array in the model's parameter order,
x0 as an array of the model's state dimension, every default filled in from the schema
(``workflow/schemas/config.schema.yaml``), so no stage re-reads the entry with defaults of
its own.
"""

from __future__ import annotations

import copy
import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any

import numpy as np

from ..models import MODELS, StateSpaceModel, get_model
from ..models.base import PriorChoice
from .blocks import joint_map_settings, stan_settings
from .schema import ConfigError, scenario_schema, schema_problems, short_repr


def entry_problems(entry: dict[str, Any]) -> list[str]:
    """Every way one scenario entry (of ``scenarios``, or a cell of an observability map)
    is invalid, each naming key, value and what is allowed; empty when it is valid.

    The schema first (its defaults are filled into ``entry``, in place), then what it cannot
    say: a known model and true values it accepts, ``stan_init`` against ``joint_map``,
    ``stan_every`` against ``K``, ``joint_map_start`` against the model."""
    problems = schema_problems(entry, scenario_schema())
    if problems:
        return problems
    if entry["stan_init"] == "joint_map" and not entry["joint_map"]:
        problems.append(
            "stan_init = 'joint_map': the chains start at the joint MAP, so joint_map must be true"
        )
    if entry.get("stan_every", 1) > entry["K"]:
        problems.append(
            f"stan_every = {entry['stan_every']}: larger than K = {entry['K']}; allowed: "
            f"1 to K (every m-th of the K design trajectories)"
        )
    model = MODELS.get(entry["model"])
    if model is None:
        problems.append(
            f"model = {short_repr(entry['model'])}: unknown model; allowed: {sorted(MODELS)}"
        )
        return problems
    problems += model.check_true_values(
        entry["omega"], entry["x0"], entry.get("prior"), T=entry["T"]
    )
    if entry["joint_map_start"] == "sign_of_x0" and not model.has_sign_consistent_start:
        problems.append(
            f"joint_map_start = 'sign_of_x0': model {entry['model']!r} has no sign-consistent "
            f"start; allowed: 'observations'"
        )
    return problems


def _frozen_array(values: Any) -> np.ndarray:
    arr = np.array(values, dtype=float)
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True, eq=False)
class Scenario:
    """A scenario of Section IV: model, true values (Omega, x0), horizon T, K and settings.

    Build it with :meth:`from_config`; the fields mirror the keys of a ``scenarios`` entry
    (``config/README.md``), with ``omega`` an array in ``model.param_names`` order and ``x0``
    an array of ``model.state_dim`` components (both read-only).
    """

    name: str
    model: StateSpaceModel
    omega: np.ndarray
    x0: np.ndarray
    T: int
    K: int
    #: prior variant for all parameters, a mapping parameter -> variant or interval
    #: [lower, upper], or None (the paper's choice per parameter; see
    #: :meth:`StateSpaceModel.prior_bounds`)
    prior: str | Mapping[str, PriorChoice] | None
    method: str
    seed: int
    joint_map: bool
    stan: bool
    stan_init: str
    joint_map_start: str
    #: starts of the joint MAP per trajectory, or None (the joint_map block's n_starts)
    joint_map_n_starts: int | None
    #: the exact marginal stage is enabled (it runs only for models linear in the states)
    exact: bool
    exact_K: int | None
    stan_batch_size: int | None
    #: the Stan stage runs on trajectories k = 0, m, 2m, ... (``stan_every``, absent = 1)
    stan_every: int
    #: NUTS settings that differ from the config's stan block, as sorted (key, value) pairs
    stan_settings: tuple[tuple[str, Any], ...]
    #: one Stan seed for every trajectory, or None (a seed per trajectory)
    stan_seed: int | None
    paper_ref: str
    description: str

    # ---------------------------------------------------------------- construction
    @classmethod
    def from_config(cls, entry: Mapping[str, Any]) -> Scenario:
        """The Scenario of one entry of the config's ``scenarios`` list.

        Missing optional keys take the schema's defaults.  Raises
        :class:`~ssmobs.config.schema.ConfigError` naming the scenario, the key, the value and
        what is allowed for every problem :func:`entry_problems` finds.
        """
        if not isinstance(entry, Mapping):
            raise ConfigError(
                f"a scenario must be a mapping of keys to values, got {type(entry).__name__}"
            )
        sc = copy.deepcopy(dict(entry))
        where = f"scenario '{sc.get('name', '?')}'"
        problems = entry_problems(sc)  # also fills in the defaults
        if problems:
            raise ConfigError(f"invalid {where}:\n  - " + "\n  - ".join(problems))
        model = get_model(sc["model"])
        prior = sc.get("prior")
        return cls(
            name=sc["name"],
            model=model,
            omega=_frozen_array(model.omega_array(sc["omega"])),
            x0=_frozen_array(np.atleast_1d(np.asarray(sc["x0"], dtype=float))),
            T=int(sc["T"]),
            K=int(sc["K"]),
            prior=MappingProxyType(dict(prior)) if isinstance(prior, Mapping) else prior,
            method=sc["method"],
            seed=int(sc["seed"]),
            joint_map=bool(sc["joint_map"]),
            stan=bool(sc["stan"]),
            stan_init=sc["stan_init"],
            joint_map_start=sc["joint_map_start"],
            joint_map_n_starts=sc.get("joint_map_n_starts"),
            exact=bool(sc.get("exact", True)),
            exact_K=sc.get("exact_K"),
            stan_batch_size=sc.get("stan_batch_size"),
            stan_every=int(sc.get("stan_every", 1)),
            stan_settings=tuple(sorted((sc.get("stan_settings") or {}).items())),
            stan_seed=sc.get("stan_seed"),
            paper_ref=sc["paper_ref"],
            description=sc["description"],
        )

    def replace(self, **changes: Any) -> Scenario:
        """A copy with some fields changed (e.g. another K, method or seed)."""
        return dataclasses.replace(self, **changes)

    # ---------------------------------------------------------------- derived facts
    @property
    def slug(self) -> str:
        """The model's slug (the config's ``model``)."""
        return self.model.slug

    @property
    def disturbance_dim(self) -> int:
        """q = (d + p) T: the dimension of one design disturbance vector (Sec. III.A)."""
        return (self.model.obs_dim + self.model.state_dim) * self.T

    @property
    def prior_config(self) -> str | dict[str, PriorChoice] | None:
        """The prior as the config gives it (plain data, e.g. for JSON)."""
        return dict(self.prior) if isinstance(self.prior, Mapping) else self.prior

    def prior_bounds(self) -> Any:
        """Support of the flat prior on Omega (:meth:`StateSpaceModel.prior_bounds`)."""
        return self.model.prior_bounds(self.omega, self.prior)

    @property
    def exact_applies(self) -> bool:
        """The exact stage runs: enabled and the model is linear in the states (issue 11)."""
        return self.exact and self.model.linear_in_states

    @property
    def exact_trajectories(self) -> int:
        """K of the design trajectories of the exact stage (``exact_K``, else K)."""
        return int(self.exact_K or self.K)

    @property
    def stan_trajectories(self) -> range:
        """The trajectories k of the Stan stage: every ``stan_every``-th of the K."""
        return range(0, self.K, self.stan_every)

    def stan_batches(self, batch_size: int) -> list[range]:
        """The trajectories k of each Stan job: consecutive runs of ``batch_size`` of
        :attr:`stan_trajectories`; a pure function of both."""
        ks = self.stan_trajectories
        return [ks[i : i + batch_size] for i in range(0, len(ks), batch_size)]

    def stan_config(self, stan_cfg: Mapping[str, Any]) -> dict[str, Any]:
        """The config's stan block with this scenario's ``stan_settings`` over it
        (:func:`stan_settings`)."""
        return stan_settings({"stan_settings": dict(self.stan_settings)}, stan_cfg)

    def joint_map_config(
        self, joint_map_cfg: Mapping[str, Any], *, single_start: bool = False
    ) -> dict[str, Any]:
        """The config's joint_map block with this scenario's start of the states and number
        of starts (:func:`joint_map_settings`)."""
        own = {
            "joint_map_start": self.joint_map_start,
            "joint_map_n_starts": self.joint_map_n_starts,
        }
        return joint_map_settings(own, joint_map_cfg, single_start=single_start)

    def batch_size(self, stan_cfg: Mapping[str, Any]) -> int:
        """Trajectories per Stan job: ``stan_batch_size``, else the config's ``stan.batch_size``."""
        return int(self.stan_batch_size or stan_cfg["batch_size"])
