"""A model's Python module checked against itself (step 1 of :mod:`ssmobs.model_check.check`,
also run by the config's validation of a user's model): the simulator's shapes and values,
the symbolic derivatives against finite differences, and the simulated disturbances
recovered by the log-density terms.
"""

from __future__ import annotations

import functools
import zlib
from collections.abc import Sequence
from typing import Any

import numpy as np
import sympy as sp

from .base import StateSpaceModel
from .check_cases import CheckCase, default_cases, sample_theta
from .log_posterior import neg2_log_posterior

#: the horizon of the model check's trajectories (short: the checks are of the formulas)
CHECK_T = 6


def model_check_seed(model: StateSpaceModel) -> int:
    """The model check's default seed: fixed per model, so a message is reproducible."""
    return zlib.crc32(model.slug.encode())


def python_stage_problems(
    model: StateSpaceModel,
    cases: Sequence[CheckCase] | None = None,
    T: int = CHECK_T,
    seed: int | None = None,
) -> list[str]:
    """Step 1 of the model check over its cases (default :func:`default_cases`): the true
    values, :func:`python_problems`, then :func:`simulate_problems`; the problems of the
    first case that has any, each labelled with the case (one mistake, one message)."""
    cases = list(cases) if cases else default_cases(model)
    seed = model_check_seed(model) if seed is None else seed
    for i, case in enumerate(cases):
        problems = model.check_true_values(case.omega, case.x0, case.prior)
        if not problems:
            problems = python_problems(model, case, T=T, seed=seed + i)
        if not problems:
            problems = simulate_problems(model, case, T=T, seed=seed + i)
        if problems:  # the same mistake shows in every case: report the first
            return [f"[python, {case.label()}] {p}" for p in problems]
    return []


def python_problems(
    model: StateSpaceModel, case: CheckCase, T: int = 5, n_points: int = 3, seed: int = 0
) -> list[str]:
    """Simulator and start shapes, and derivatives against central finite differences."""
    problems: list[str] = []
    rng = np.random.default_rng(seed)
    K, p, d = 3, model.state_dim, model.obs_dim
    omega = model.omega_array(case.omega)
    x0 = np.asarray(case.x0, dtype=float)
    eta, eps = rng.standard_normal((K, T, p)), rng.standard_normal((K, T, d))
    try:
        out = model.simulate(omega, x0, eta, eps)
    except Exception as err:  # noqa: BLE001 - reported as a problem
        return [f"simulate raised {type(err).__name__}: {err}"]
    if not (isinstance(out, tuple) and len(out) == 2):
        return [f"simulate must return a tuple (x, z), got {type(out).__name__}"]
    x, z = (np.asarray(a) for a in out)
    for name, arr, want in (("x", x, (K, T, p)), ("z", z, (K, T, d))):
        if arr.shape != want:
            problems.append(
                f"simulate returned {name} of shape {arr.shape} for K={K}, T={T}; "
                f"expected (K, T, {'p' if name == 'x' else 'd'}) = {want} "
                f"(state_dim p={p}, obs_dim d={d})"
            )
        elif not np.all(np.isfinite(arr)):
            problems.append(f"simulate returned non-finite {name} at {case.label()}")
    if problems:
        return problems
    start = np.asarray(model.initial_states(omega, z))
    if start.shape != (K, T, p) or not np.all(np.isfinite(start)):
        problems.append(
            f"initial_states returned shape {start.shape} (finite: "
            f"{bool(np.all(np.isfinite(start)))}); expected finite (K, T, p) = "
            f"{(K, T, p)}"
        )
    theta, z1, bounds = sample_theta(model, case, T, n_points, rng)
    value, grad, hess = neg2_log_posterior(model, theta, z1, bounds, order=2)
    if not np.all(np.isfinite(value)):
        bad = theta[~np.isfinite(value)][0]
        return problems + [
            f"-2 log posterior is not finite at Theta = {bad.tolist()} inside the "
            f"support ({case.label()})"
        ]
    names = model.theta_names(T)
    n = theta.shape[1]
    for j in range(n):
        h = 1e-6 * (1.0 + np.abs(theta[:, j]))
        e = np.zeros_like(theta)
        e[:, j] = h
        fp, gp = neg2_log_posterior(model, theta + e, z1, order=1)
        fm, gm = neg2_log_posterior(model, theta - e, z1, order=1)
        fd_g = (fp - fm) / (2 * h)
        fd_h = (gp - gm) / (2 * h[:, None])
        err_g = np.abs(grad[:, j] - fd_g) / (1.0 + np.abs(fd_g))
        if err_g.max() > 1e-4:
            i = int(err_g.argmax())
            problems.append(
                f"gradient of -2 log posterior in {names[j]} is {grad[i, j]:.6g}, "
                f"finite differences give {fd_g[i]:.6g} at Theta = "
                f"{theta[i].tolist()}"
            )
        err_h = np.abs(hess[:, :, j] - fd_h) / (1.0 + np.abs(fd_h))
        if err_h.max() > 1e-4:
            i_row, r_col = np.unravel_index(int(err_h.argmax()), err_h.shape)
            i, r = int(i_row), int(r_col)
            problems.append(
                f"Hessian entry ({names[r]}, {names[j]}) of -2 log posterior is "
                f"{hess[i, r, j]:.6g}, finite differences give {fd_h[i, r]:.6g}"
            )
    return problems


# ---------------------------------------------------------------------- 1b. simulate vs terms
@functools.cache
def _whitening_functions(model: StateSpaceModel) -> tuple[Any, Any]:
    """Lambdified gradient and Hessian of the observation term in z_t and of the
    transition term in x_t (each Gaussian, Eq. (1)): for a term (v - m)' S^-1 (v - m) +
    log det S, g = 2 S^-1 (v - m) and H = 2 S^-1, so g' H^-1 g / 2 is the squared norm of
    the standardized disturbance that produced v, whatever square root of S simulates it."""
    m, p, d = model.n_params, model.state_dim, model.obs_dim
    w = list(sp.symbols(f"w0:{m}"))
    xp, xt, zt = (
        list(sp.symbols(f"xp0:{p}")),
        list(sp.symbols(f"x0:{p}")),
        list(sp.symbols(f"z0:{d}")),
    )

    def derivs(expr: sp.Expr, wrt: list[sp.Symbol]) -> list[sp.Expr]:
        grad = [sp.diff(expr, v) for v in wrt]
        return grad + [sp.diff(g, v) for g in grad for v in wrt]

    obs = sp.lambdify(w + xt + zt, derivs(model.obs_term(w, xt, zt), zt), modules="numpy")
    trans = sp.lambdify(w + xp + xt, derivs(model.trans_term(w, xp, xt), xt), modules="numpy")
    return obs, trans


def _squared_norms(func: Any, args: list[np.ndarray], n: int) -> np.ndarray:
    """g' H^-1 g / 2 for each point of the broadcast ``args``, from ``func``'s list
    (n gradient entries, then the n x n Hessian row by row); NaN where H is singular."""
    shape = np.broadcast(*args).shape
    with np.errstate(all="ignore"):
        raw = [np.broadcast_to(np.asarray(v, dtype=float), shape) for v in func(*args)]
    g = np.stack(raw[:n], axis=-1)
    H = np.stack(raw[n:], axis=-1).reshape(shape + (n, n))
    out = np.full(shape, np.nan)
    ok = np.isfinite(H).all(axis=(-2, -1)) & np.isfinite(g).all(axis=-1)
    ok[ok] = np.abs(np.linalg.det(H[ok])) > 0
    out[ok] = 0.5 * np.einsum(
        "...i,...i->...", g[ok], np.linalg.solve(H[ok], g[ok][..., None])[..., 0]
    )
    return out


def simulate_problems(
    model: StateSpaceModel, case: CheckCase, T: int = 5, seed: int = 0, rtol: float = 1e-8
) -> list[str]:
    """``simulate`` against the model's own terms: trajectories simulated from known
    disturbances must give exactly those disturbances' squared norms back through the
    observation term (eps_t) and the transition term (eta_t).  Catches a simulator whose
    parameters are swapped or whose equations differ from the log posterior's."""
    rng = np.random.default_rng(seed)
    K, p, d = 3, model.state_dim, model.obs_dim
    omega = model.omega_array(case.omega)
    x0 = np.asarray(case.x0, dtype=float)
    eta, eps = rng.standard_normal((K, T, p)), rng.standard_normal((K, T, d))
    x, z = (np.asarray(a, dtype=float) for a in model.simulate(omega, x0, eta, eps))
    prev = np.concatenate([np.broadcast_to(x0, (K, 1, p)), x[:, :-1]], axis=1)
    obs, trans = _whitening_functions(model)
    w = [np.full((K, T), v) for v in omega]
    problems = []
    for term, func, args, noise, n in (
        (
            "observation",
            obs,
            w + [x[..., i] for i in range(p)] + [z[..., j] for j in range(d)],
            eps,
            d,
        ),
        (
            "transition",
            trans,
            w + [prev[..., i] for i in range(p)] + [x[..., i] for i in range(p)],
            eta,
            p,
        ),
    ):
        got = _squared_norms(func, args, n)
        want = np.sum(noise**2, axis=-1)
        err = np.abs(got - want) / (1.0 + want)
        if not np.all(err <= rtol):  # NaN (singular Hessian) counts as a mismatch
            k, t = np.unravel_index(
                int(np.nanargmax(np.where(np.isnan(err), np.inf, err))), err.shape
            )
            name = "eps" if term == "observation" else "eta"
            bad = np.flatnonzero(~(err[k] <= rtol)) + 1
            where = (
                f"at every t = 1..{T}"
                if bad.size == T
                else f"at t = {', '.join(str(v) for v in bad)} (of 1..{T})"
            )
            problems.append(
                f"simulate does not match the {term} term {where} of a trajectory simulated "
                f"from known disturbances; at t={t + 1}, with |{name}_t|^2 = {want[k, t]:.6g}, "
                f"the {term} term gives back "
                f"{got[k, t]:.6g} at the same true values ({case.label()}); check the order of "
                f"the parameters in simulate (param_names = {list(model.param_names)}) and its "
                f"equations against {'obs_term' if term == 'observation' else 'trans_term'}"
            )
    return problems
