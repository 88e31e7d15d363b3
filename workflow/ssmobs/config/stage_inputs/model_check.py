"""What rules check_model and check_model_stan read: one scenario's case of the model check
(the Python model against itself, and against its Stan program before NUTS, Sec. III.C)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from ..blocks import stan_gradients
from .frozen import TruthViews, frozen, plain


def check_case(sc: Mapping[str, Any]) -> dict[str, Any]:
    """What the model check reads of scenario entry ``sc``
    (:func:`ssmobs.models.check_cases.cases_from_scenarios`): its model, true values and
    start, and its prior where that is an interval prior (a parameter with its own
    ``[lower, upper]``), which is checked as configured; a named prior variant is no input,
    as every variant of the model is checked whichever the scenario picks
    (:func:`ssmobs.models.check_cases.prior_variant_cases`)."""
    case = {n: sc.get(n) for n in ("model", "omega", "x0")}
    prior = sc.get("prior")
    if isinstance(prior, Mapping) and any(not isinstance(v, str) for v in prior.values()):
        case["prior"] = dict(prior)
    return case


@dataclass(frozen=True)
class ModelCheckInputs(TruthViews):
    """Everything the model check of one scenario reads: the model, the scenario's case
    (:func:`check_case`: true values, start and interval prior, frozen), whether the check
    runs against the Stan program, and the gradient path that program takes
    (``stan.gradients`` for a model with its own ``stan/<model>.stan``, else ``autodiff``:
    a generated program is checked the same way whatever the setting).  Its content is the
    check's key with the code (:meth:`ssmobs.cache_keys.CacheKeys.check_model`)."""

    model: str
    #: the true parameters and initial state as the config gives them (frozen)
    omega: Any
    x0: Any
    #: the interval prior as (parameter, bounds or variant) pairs, or None (no interval)
    prior: tuple[tuple[str, Any], ...] | None
    #: against the Stan program (rule check_model_stan), or the Python model alone
    against_stan: bool
    gradients: str

    @property
    def case_config(self) -> dict[str, Any]:
        """The case as :func:`check_case` gives it (the scenario entry the check's cases are
        built from, :func:`ssmobs.models.check_cases.cases_from_scenarios`)."""
        case = {"model": self.model, "omega": self.omega_config, "x0": self.x0_config}
        return case if self.prior is None else {**case, "prior": plain(self.prior)}


def model_check_inputs(
    entry: Mapping[str, Any],
    config: Mapping[str, Any],
    *,
    against_stan: bool = False,
    own_program: bool = True,
) -> ModelCheckInputs:
    """The inputs of the model check of the scenario ``entry``: of the Python model alone
    (rule check_model) or ``against_stan`` (rule check_model_stan), whose model has a
    hand-written Stan program where ``own_program``."""
    case = check_case(entry)
    prior = case.get("prior")
    return ModelCheckInputs(
        model=str(entry["model"]),
        omega=frozen(case["omega"]),
        x0=frozen(case["x0"]),
        prior=None if prior is None else frozen(prior),
        against_stan=bool(against_stan),
        gradients=stan_gradients(config["stan"]) if against_stan and own_program else "autodiff",
    )


def model_check_stan_inputs(
    entry: Mapping[str, Any], config: Mapping[str, Any], *, own_program: bool
) -> ModelCheckInputs:
    """:func:`model_check_inputs` against the Stan program (rule check_model_stan)."""
    return model_check_inputs(entry, config, against_stan=True, own_program=own_program)
