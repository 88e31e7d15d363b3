"""The analytic gradients of the model check (:mod:`ssmobs.model_check.check`, step 4): the log
density and gradient generated from the model's terms (:mod:`ssmobs.nuts.analytic_gradients`)
against Stan's autodiff of the hand-written statements.  The analytic program holds both
model blocks (:func:`ssmobs.nuts.analytic_program.analytic_stan_code`), so one compile
serves NUTS and this check: the native driver's ``--log-density`` mode evaluates it at the
same random points inside the support as it is and with ``--autodiff-twin``; Stan's log
density, then the sampler's (``--sampler-gradient``: Jacobian included, and for the
generated function the gradient it writes without Stan's tape, ``ssmobs/gradient_slot.hpp``).

The values may differ by one additive constant (the hand-written program keeps Stan's
normalising constants there); the gradients on the unconstrained scale must be equal.  Both
to ``rtol`` relative (1e-12: what is left is rounding in another summation order).  The
first disagreement is one line naming the point and the component.

A model without a hand-written program runs a generated one
(:func:`ssmobs.nuts.analytic_program.generated_stan_code`), which has no autodiff twin:
:func:`generated_problems` compares its gradient with the Python model's instead.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..models import StateSpaceModel
from ..models.check_cases import CheckCase, sample_theta
from ..nuts.analytic_gradients import switch_name
from ..nuts.analytic_program import AnalyticProgram, write_analytic_program
from .stan import stan_point

if TYPE_CHECKING:
    from ..stan_backends.native_run import LogDensities

#: relative tolerance of value (up to a constant) and gradient
ANALYTIC_RTOL = 1e-12
#: relative tolerance of a generated program's gradient against the Python model's (NumPy
#: evaluates the same terms in another form; Stan's bound transforms round in between)
GENERATED_RTOL = 1e-10


def unconstrained_names(names: list[str], dims: list[list[int]]) -> list[str]:
    """Stan's unconstrained coordinates by name (arrays and matrices column-major)."""
    out: list[str] = []
    for name, dim in zip(names, dims):
        if not dim:
            out.append(name)
            continue
        idx = np.indices(dim).reshape(len(dim), -1).T
        order = np.lexsort(idx.T)  # column-major: the first index runs fastest
        out.extend(f"{name}[{','.join(str(i + 1) for i in idx[j])}]" for j in order)
    return out


def analytic_problems(
    model: StateSpaceModel,
    stan_path: Path,
    case: CheckCase,
    T: int = 6,
    n_points: int = 6,
    seed: int = 0,
    rtol: float = ANALYTIC_RTOL,
    program: AnalyticProgram | None = None,
) -> list[str]:
    """Analytic against autodiff for one case (empty list: they agree).  ``program``: the
    program to check (the model check passes the one it runs,
    :func:`ssmobs.model_check.program.checked_program`; None, for a direct call: generated
    here from the model and its Stan program ``stan_path``, written into the program cache
    as the build job would write it).  The autodiff side is the program's own twin when it
    holds both model blocks (one compile), else ``stan_path`` compiled apart (a whole
    generated program against a hand-written one)."""
    from ..stan_backends.native import NativeBackend

    rng = np.random.default_rng(seed)
    theta, z, bounds = sample_theta(model, case, T, n_points, rng)
    data = model.stan_data(z, bounds)
    program = program or write_analytic_program(model, stan_path)
    points = [stan_point(model, th, T) for th in theta]
    native = NativeBackend()
    label = f"analytic gradients of '{model.slug}' ({case.label()})"
    has_twin = f"{switch_name(model)}()" in program.stan_file.read_text()
    for sampler in (False, True):
        try:
            if has_twin:
                auto = native.log_density(
                    program.stan_file, data, points, program.header, sampler, twin=True
                )
            else:
                auto = native.log_density(stan_path, data, points, sampler=sampler)
            ana = native.log_density(program.stan_file, data, points, program.header, sampler)
        except (ValueError, RuntimeError) as err:
            return [f"{label}: {_first_line(err)}"]
        what = "the sampler's gradient" if sampler else "gradient"
        problem = _compare(auto, ana, f"{label}", what, rtol)
        if problem is not None:
            return [problem]
    return []


def _first_line(err: Exception) -> str:
    """The first line of a backend's error, or its type's name when it has no text."""
    text = str(err).strip()
    return text.splitlines()[0] if text else type(err).__name__


def _largest_gap(got: np.ndarray, want: np.ndarray, tol: float) -> int | None:
    """The component where ``got`` differs most from ``want``, if by more than ``tol``."""
    j = int(np.argmax(np.abs(got - want)))
    return j if abs(got[j] - want[j]) > tol else None


def _compare(
    auto: LogDensities, ana: LogDensities, label: str, what: str, rtol: float
) -> str | None:
    """The first disagreement of the analytic program's log densities with the autodiff
    program's (values up to one constant, gradients equal to ``rtol``), or None."""
    names = unconstrained_names(auto.param_names, auto.dims)
    ref: float | None = None
    for i, (va, vs, ga, gs) in enumerate(
        zip(ana.values, auto.values, ana.gradients, auto.gradients)
    ):
        if (va is None) != (vs is None):
            which = "analytic" if va is None else "autodiff"
            return f"{label}: the {which} model block alone rejects point {i}"
        if va is None or vs is None or ga is None or gs is None:
            continue
        gap = va - vs
        ref = gap if ref is None else ref
        if abs(gap - ref) > rtol * max(1.0, abs(vs)):
            return (
                f"{label}: log density differs from Stan's autodiff by more than a constant: "
                f"analytic - autodiff = {ref:.17g} at the first point, {gap:.17g} at point {i}"
            )
        g_a, g_s = np.asarray(ga), np.asarray(gs)
        scale = max(1.0, float(np.max(np.abs(g_s))))
        j = _largest_gap(g_a, g_s, rtol * scale)
        if j is not None:
            return (
                f"{label}: {what} in {names[j]} differs from Stan's autodiff at point {i}: "
                f"{g_a[j]:.17g} vs {g_s[j]:.17g} (relative {abs(g_a[j] - g_s[j]) / scale:.2g} "
                f"> {rtol:g})"
            )
    if ref is None:
        return f"{label}: Stan rejects every random point; nothing was compared"
    return None


def _python_gradient(
    model: StateSpaceModel, theta: np.ndarray, z: np.ndarray, T: int
) -> dict[str, float]:
    """d log pi / d Theta (Eq. (2)) of the Python model by Stan's unconstrained names."""
    from ..models.log_posterior import neg2_log_posterior

    _, grad = neg2_log_posterior(model, theta, z, None, order=1)
    grad = -0.5 * np.asarray(grad)
    m, p = model.n_params, model.state_dim
    out = {name: float(grad[i]) for i, name in enumerate(model.param_names)}
    states = grad[m:].reshape(T + 1, p)
    for j in range(p):
        out["x0" if p == 1 else f"x0[{j + 1}]"] = float(states[0, j])
        for t in range(1, T + 1):
            out[f"x[{t}]" if p == 1 else f"x[{t},{j + 1}]"] = float(states[t, j])
    return out


def _bound_slope(value: float, lo: float, hi: float) -> float:
    """d theta / d u of Stan's transform of a parameter bounded by (lo, hi) (infinite: none)."""
    if np.isfinite(lo) and np.isfinite(hi):
        return (value - lo) * (hi - value) / (hi - lo)
    if np.isfinite(lo):
        return value - lo
    if np.isfinite(hi):
        return hi - value
    return 1.0


def _log_slope_slope(value: float, lo: float, hi: float) -> float:
    """d/du log(d theta / d u) of the same transform: what the Jacobian adds to the
    sampler's gradient."""
    if np.isfinite(lo) and np.isfinite(hi):
        return 1.0 - 2.0 * (value - lo) / (hi - lo)
    if np.isfinite(lo) or np.isfinite(hi):
        return 1.0
    return 0.0


def generated_problems(
    model: StateSpaceModel,
    program: AnalyticProgram,
    case: CheckCase,
    T: int = 6,
    n_points: int = 6,
    seed: int = 0,
    rtol: float = GENERATED_RTOL,
) -> list[str]:
    """The generated whole program of a model without a hand-written one
    (:func:`ssmobs.nuts.analytic_program.generated_stan_code`), which has no autodiff twin: its
    gradient on Stan's unconstrained scale against the Python model's gradient of the same
    terms (NumPy's evaluation, not the C++), times the slopes of Stan's bound transforms,
    at random points inside the support (empty list: they agree)."""
    from ..nuts.analytic_program import generated_bounds
    from ..stan_backends.native import NativeBackend

    rng = np.random.default_rng(seed)
    theta, z, bounds = sample_theta(model, case, T, n_points, rng)
    data = model.stan_data(z, bounds)
    label = f"generated program of '{model.slug}' ({case.label()})"
    points = [stan_point(model, th, T) for th in theta]
    native = NativeBackend()
    try:
        dens = native.log_density(program.stan_file, data, points, program.header)
        sampler = native.log_density(program.stan_file, data, points, program.header, True)
    except (ValueError, RuntimeError) as err:
        return [f"{label}: {_first_line(err)}"]
    names = unconstrained_names(dens.param_names, dens.dims)
    box = generated_bounds(model, bounds.lower, bounds.upper)
    for i, (th, g, g_sampler) in enumerate(zip(theta, dens.gradients, sampler.gradients)):
        if g is None or g_sampler is None:
            return [f"{label}: Stan rejects point {i}, inside the Python model's support"]
        want = _python_gradient(model, th, z, T)
        jacobian = dict.fromkeys(names, 0.0)
        for j, (lo, hi) in enumerate(box):
            want[model.param_names[j]] *= _bound_slope(float(th[j]), lo, hi)
            jacobian[model.param_names[j]] = _log_slope_slope(float(th[j]), lo, hi)
        g_py = np.array([want[n] for n in names])
        g_st = np.asarray(g, dtype=float)
        g_sa = np.asarray(g_sampler, dtype=float)
        scale = max(1.0, float(np.max(np.abs(g_py))))
        checks = (
            (g_st, g_py, rtol, "gradient in {} differs from the Python model's"),
            # the sampler's gradient (no tape): that plus d/du of the log Jacobian
            (
                g_sa,
                g_st + np.array([jacobian[n] for n in names]),
                ANALYTIC_RTOL,
                "the sampler's gradient in {} differs from the log density's plus its Jacobian's",
            ),
        )
        for got, expected, tol, what in checks:
            k = _largest_gap(got, expected, tol * scale)
            if k is not None:
                return [
                    f"{label}: {what.format(names[k])} at point {i}: {got[k]:.17g} vs "
                    f"{expected[k]:.17g} (relative {abs(got[k] - expected[k]) / scale:.2g} "
                    f"> {tol:g})"
                ]
    return []
