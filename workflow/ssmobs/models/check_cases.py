"""The cases of the model check (:mod:`ssmobs.models.self_check`,
:mod:`ssmobs.model_check.check`): true values and priors at which the Python model and the
Stan program are compared, and random points inside their support.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from .base import PriorBounds, StateSpaceModel
from .log_posterior import in_support


class ModelCheckError(ValueError):
    """The model's Python module and Stan program disagree; the message lists every problem."""


@dataclass(frozen=True)
class CheckCase:
    """True values and prior for which the two files are compared."""

    omega: dict[str, float]
    x0: list[float]
    prior: str | dict[str, Any] | None = None

    def label(self) -> str:
        return f"omega={self.omega}, x0={self.x0}, prior={self.prior}"


def default_values(model: StateSpaceModel) -> tuple[dict[str, float], list[float]]:
    """True values of the default cases: a distinct value per parameter, evenly spaced in
    (0.3, 0.7) (inside every prior variant's support and the paper's constraints), so that
    swapped parameters change the numbers; x0 distinct from them (0.75, 1.0, ...)."""
    m = model.n_params
    omega = {n: round(0.3 + 0.4 * (j + 1) / (m + 1), 6) for j, n in enumerate(model.param_names)}
    return omega, [0.75 + 0.25 * i for i in range(model.state_dim)]


def default_cases(model: StateSpaceModel) -> list[CheckCase]:
    """Cases when no config is given: :func:`default_values` with the default prior and
    each allowed variant of each parameter in turn, so that every prior bound the model
    can produce is compared."""
    return prior_variant_cases(model, CheckCase(*default_values(model)))


def prior_variant_cases(model: StateSpaceModel, case: CheckCase) -> list[CheckCase]:
    """``case``'s true values with the default prior and each allowed variant of each
    parameter in turn (prior bounds are per parameter, so every bound is compared): the
    check of a scenario does not depend on which prior the scenario picks, and changing
    the prior needs no new check (and no new design trajectories).  A prior with an interval
    [lower, upper] (the config's own bounds) is checked as configured besides."""
    cases = [CheckCase(case.omega, case.x0, None)]
    for name in model.param_names:
        for variant in model.allowed_priors[name]:
            if variant != model.default_prior[name]:
                cases.append(CheckCase(case.omega, case.x0, {name: variant}))
    # an interval prior of the config is the user's own: checked as configured (issue 47)
    if isinstance(case.prior, Mapping) and any(not isinstance(v, str) for v in case.prior.values()):
        cases.append(case)
    return [c for c in cases if not model.check_true_values(c.omega, c.x0, c.prior)]


def x0_values(sc: Mapping[str, Any]) -> list[float]:
    """A scenario entry's x0 (a number or a list in the config) as a list of floats."""
    x0 = sc["x0"]
    return [float(v) for v in (x0 if isinstance(x0, list) else [x0])]


def cases_from_scenarios(scenarios: Sequence[Mapping[str, Any]], slug: str) -> list[CheckCase]:
    """One case per distinct (omega, x0, prior) of the config's scenarios of this model."""
    out: list[CheckCase] = []
    for sc in scenarios:
        if sc["model"] != slug:
            continue
        case = CheckCase(
            {k: float(v) for k, v in sc["omega"].items()}, x0_values(sc), sc.get("prior")
        )
        if case not in out:
            out.append(case)
    return out


def random_omega(
    model: StateSpaceModel, bounds: PriorBounds, rng: np.random.Generator, n: int
) -> np.ndarray:
    """n points strictly inside the prior box and the model constraints."""
    lo = np.where(np.isfinite(bounds.lower), bounds.lower, bounds.upper - 3.0)
    hi = np.where(np.isfinite(bounds.upper), bounds.upper, bounds.lower + 3.0)
    lo = np.where(np.isfinite(lo), lo, -3.0)
    hi = np.where(np.isfinite(hi), hi, 3.0)
    cand = lo + (hi - lo) * rng.uniform(0.05, 0.95, size=(50 * n, model.n_params))
    inside = cand[in_support(model, cand, bounds)]
    if inside.shape[0] < n:
        raise ModelCheckError(
            f"model '{model.slug}': found no points inside the support of "
            f"the prior box ({bounds.lower}, {bounds.upper}) and the model "
            f"constraints"
        )
    return inside[:n]


def sample_theta(
    model: StateSpaceModel, case: CheckCase, T: int, n: int, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray, Any]:
    """n random Theta inside the support and one simulated z (T, d) for the case."""
    bounds = model.prior_bounds(case.omega, case.prior)
    omega_true = model.omega_array(case.omega)
    x0 = np.asarray(case.x0, dtype=float)
    eta = rng.standard_normal((1, T, model.state_dim))
    eps = rng.standard_normal((1, T, model.obs_dim))
    x, z = model.simulate(omega_true, x0, eta, eps)
    omega = random_omega(model, bounds, rng, n)
    states = np.concatenate([np.broadcast_to(x0, (1, model.state_dim)), x[0]], axis=0)
    states = states[None] + rng.normal(0.0, 0.5, size=(n, T + 1, model.state_dim))
    return np.concatenate([omega, states.reshape(n, -1)], axis=1), z[0], bounds
