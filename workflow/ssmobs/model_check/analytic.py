"""The analytic gradients of the model check (:mod:`ssmobs.model_check.check`, step 4): the log
density and gradient generated from the model's terms (:mod:`ssmobs.nuts.analytic_gradients`)
against Stan's autodiff of the hand-written program, both evaluated by the native driver's
``--log-density`` mode at the same random points inside the support.

The values may differ by one additive constant (the hand-written program keeps Stan's
normalising constants there); the gradients on the unconstrained scale must be equal.  Both
to ``rtol`` relative (1e-12: what is left is rounding in another summation order).  The
first disagreement is one line naming the point and the component.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..models import StateSpaceModel
from ..nuts.analytic_gradients import AnalyticProgram, write_analytic_program
from .cases import CheckCase, sample_theta
from .stan import stan_point

#: relative tolerance of value (up to a constant) and gradient
ANALYTIC_RTOL = 1e-12


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
    generated program to check (default: generated from the model and ``stan_path``)."""
    from ..stan_backends.native import NativeBackend

    rng = np.random.default_rng(seed)
    theta, z, bounds = sample_theta(model, case, T, n_points, rng)
    data = model.stan_data(z, bounds)
    program = program or write_analytic_program(model, stan_path)
    points = [stan_point(model, th, T) for th in theta]
    native = NativeBackend()
    try:
        auto = native.log_density(stan_path, data, points)
        ana = native.log_density(program.stan_file, data, points, program.header)
    except (ValueError, RuntimeError) as err:
        first = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
        return [f"analytic gradients of '{model.slug}' ({case.label()}): {first}"]
    label = f"analytic gradients of '{model.slug}' ({case.label()})"
    names = unconstrained_names(auto.param_names, auto.dims)
    ref: float | None = None
    for i, (va, vs, ga, gs) in enumerate(
        zip(ana.values, auto.values, ana.gradients, auto.gradients)
    ):
        if (va is None) != (vs is None):
            which = "analytic" if va is None else "autodiff"
            return [f"{label}: the {which} program alone rejects point {i}"]
        if va is None or vs is None or ga is None or gs is None:
            continue
        gap = va - vs
        ref = gap if ref is None else ref
        if abs(gap - ref) > rtol * max(1.0, abs(vs)):
            return [
                f"{label}: log density differs from Stan's autodiff by more than a constant: "
                f"analytic - autodiff = {ref:.17g} at the first point, {gap:.17g} at point {i}"
            ]
        g_a, g_s = np.asarray(ga), np.asarray(gs)
        scale = max(1.0, float(np.max(np.abs(g_s))))
        j = int(np.argmax(np.abs(g_a - g_s)))
        if abs(g_a[j] - g_s[j]) > rtol * scale:
            return [
                f"{label}: gradient in {names[j]} differs from Stan's autodiff at point {i}: "
                f"{g_a[j]:.17g} vs {g_s[j]:.17g} (relative {abs(g_a[j] - g_s[j]) / scale:.2g} "
                f"> {rtol:g})"
            ]
    if ref is None:
        return [f"{label}: Stan rejects every random point; nothing was compared"]
    return []
