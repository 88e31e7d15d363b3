"""Check a model's Python module and Stan program against each other, for any model.

The Python model (``workflow/ssmobs/models/<slug>.py``) drives the joint MAP (Sec. III.B)
and the Stan program (``stan/<slug>.stan``) the marginal MAP (Sec. III.C); the paper's
comparison of the two is only meaningful when both encode the same log posterior (2).
:func:`check_model` tells exactly what disagrees, cheapest checks first:

1. Python alone: the simulator (Eq. (1)) and ``initial_states`` return the declared
   shapes and finite values; the symbolic gradient and Hessian of -2 pi match central finite
   differences at random points inside the prior support.
2. Stan source, without compiling: the ``parameters`` block declares exactly
   ``(*param_names, x0, x)`` in this order, and the ``data`` block declares ``T``, ``z`` and
   the prior bounds ``<name>_lower`` / ``<name>_upper`` of every parameter.
3. Compiled Stan (the native driver's ``--log-density`` mode, or PyStan's ``log_prob``;
   the model block without Jacobian): parameter names
   and shapes; log density equal to the Python one up to one additive constant at random
   points inside the support; the support itself equal to Python's (points just inside
   every finite prior bound are accepted, points just outside and points violating a model
   constraint are rejected).

Run as ``python -m ssmobs.check_model <slug> [--configfile config/x.yaml]``; the Snakemake
rule ``check_model`` runs it for every model a config uses, before any design trajectory.
"""

from __future__ import annotations

import argparse
import functools
import json
import re
import sys
import zlib
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import sympy as sp

from .models import PriorBounds, StateSpaceModel, get_model
from .models.log_posterior import in_support, log_posterior, neg2_log_posterior


class ModelCheckError(ValueError):
    """The model's Python module and Stan program disagree; the message lists every problem."""


@dataclass(frozen=True)
class CheckCase:
    """True values and prior for which the two files are compared."""

    omega: dict[str, float]
    x0: list[float]
    prior: str | dict[str, str] | None = None

    def label(self) -> str:
        return f"omega={self.omega}, x0={self.x0}, prior={self.prior}"


@dataclass
class CheckReport:
    """What was checked and passed, the check that failed (``failed``, "" if none) and the
    problems it found (empty ``problems``: the model passes)."""

    slug: str
    checks: list[str] = field(default_factory=list)
    problems: list[str] = field(default_factory=list)
    failed: str = ""

    def to_dict(self) -> dict[str, Any]:
        return {
            "slug": self.slug,
            "ok": not self.problems,
            "checks": self.checks,
            "failed": self.failed,
            "problems": self.problems,
        }

    def record(self, check: str, problems: Sequence[str]) -> None:
        """A check's outcome: passed (``checks``) or the failed one with its problems."""
        if problems:
            self.failed, self.problems = check, [*self.problems, *problems]
        else:
            self.checks.append(check)


# ----------------------------------------------------------------------------- cases
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
    the prior needs no new check (and no new design trajectories)."""
    cases = [CheckCase(case.omega, case.x0, None)]
    for name in model.param_names:
        for variant in model.allowed_priors[name]:
            if variant != model.default_prior[name]:
                cases.append(CheckCase(case.omega, case.x0, {name: variant}))
    return [c for c in cases if not model.check_true_values(c.omega, c.x0, c.prior)]


def cases_from_scenarios(scenarios: Sequence[Mapping[str, Any]], slug: str) -> list[CheckCase]:
    """One case per distinct (omega, x0, prior) of the config's scenarios of this model."""
    out: list[CheckCase] = []
    for sc in scenarios:
        if sc["model"] != slug:
            continue
        x0 = sc["x0"] if isinstance(sc["x0"], list) else [sc["x0"]]
        case = CheckCase(
            {k: float(v) for k, v in sc["omega"].items()}, [float(v) for v in x0], sc.get("prior")
        )
        if case not in out:
            out.append(case)
    return out


def _random_omega(
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


def _sample_theta(
    model: StateSpaceModel, case: CheckCase, T: int, n: int, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray, Any]:
    """n random Theta inside the support and one simulated z (T, d) for the case."""
    bounds = model.prior_bounds(case.omega, case.prior)
    omega_true = model.omega_array(case.omega)
    x0 = np.asarray(case.x0, dtype=float)
    eta = rng.standard_normal((1, T, model.state_dim))
    eps = rng.standard_normal((1, T, model.obs_dim))
    x, z = model.simulate(omega_true, x0, eta, eps)
    omega = _random_omega(model, bounds, rng, n)
    states = np.concatenate([np.broadcast_to(x0, (1, model.state_dim)), x[0]], axis=0)
    states = states[None] + rng.normal(0.0, 0.5, size=(n, T + 1, model.state_dim))
    return np.concatenate([omega, states.reshape(n, -1)], axis=1), z[0], bounds


# ----------------------------------------------------------------------------- 1. Python
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
    theta, z1, bounds = _sample_theta(model, case, T, n_points, rng)
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


# ----------------------------------------------------------------------------- 2. Stan source
def _strip_comments(code: str) -> str:
    code = re.sub(r"/\*.*?\*/", " ", code, flags=re.S)
    return re.sub(r"(//|#).*", "", code)


def stan_block(code: str, name: str) -> str | None:
    """Body of the block ``name`` (e.g. ``parameters``; not ``transformed parameters``)."""
    code = _strip_comments(code)
    for match in re.finditer(rf"\b{name}\s*\{{", code):
        before = code[: match.start()].rstrip()
        if not before.endswith(("transformed", "generated")):
            break
    else:
        return None
    depth, start = 1, match.end()
    for i in range(start, len(code)):
        if code[i] == "{":
            depth += 1
        elif code[i] == "}":
            depth -= 1
            if depth == 0:
                return code[start:i]
    return None


def declared_names(block: str) -> list[str]:
    """Variable names declared in a Stan ``data`` or ``parameters`` block, in order."""
    names = []
    for stmt in block.split(";"):
        flat, prev = stmt, None
        while flat != prev:  # drop bounds <...>, sizes [...] and calls (...), innermost first
            prev, flat = flat, re.sub(r"<[^<>]*>|\[[^\[\]]*\]|\([^()]*\)", " ", flat)
        ids = re.findall(r"[A-Za-z_][A-Za-z0-9_]*", flat.split("=")[0])
        if len(ids) >= 2:  # a type and a name
            names.append(ids[-1])
    return names


def expected_parameters(model: StateSpaceModel) -> list[str]:
    """Stan parameters in Theta's order: Omega, then x0, then x."""
    return [*model.param_names, "x0", "x"]


def stan_source_problems(model: StateSpaceModel, stan_path: Path) -> list[str]:
    """Parameter names and order, and the data the Python side passes, read from the source."""
    if not stan_path.is_file():
        return [f"no Stan program {stan_path}: every model needs stan/{model.slug}.stan"]
    code = stan_path.read_text()
    problems = []
    params = stan_block(code, "parameters")
    want = expected_parameters(model)
    if params is None:
        problems.append(f"{stan_path.name}: no parameters block found")
    else:
        got = declared_names(params)
        if got != want:
            problems.append(
                f"{stan_path.name}: the parameters block declares {got}, but the Python model "
                f"'{model.slug}' (param_names = {list(model.param_names)}) needs exactly {want} "
                f"in this order: Theta = (Omega, x0, x_1..x_T)"
            )
    data = stan_block(code, "data")
    declared = declared_names(data) if data is not None else []
    needed = ["T", "z"] + [f"{n}_{s}" for n in model.param_names for s in ("lower", "upper")]
    missing = [n for n in needed if n not in declared]
    if missing:
        problems.append(
            f"{stan_path.name}: the data block does not declare {missing}; the Python model "
            f"passes T, z and the flat prior bounds <name>_lower, <name>_upper of every "
            f"parameter (ssmobs.models.base.StateSpaceModel.stan_data), and the Stan program "
            f"must bound each parameter by them"
        )
    return problems


# ----------------------------------------------------------------------------- 3. compiled Stan
def _stan_point(model: StateSpaceModel, theta: np.ndarray, T: int) -> dict:
    m, p = model.n_params, model.state_dim
    omega, states = theta[:m], theta[m:].reshape(T + 1, p)
    point: dict[str, Any] = {name: float(omega[i]) for i, name in enumerate(model.param_names)}
    point["x0"] = float(states[0, 0]) if p == 1 else states[0].tolist()
    point["x"] = states[1:, 0].tolist() if p == 1 else states[1:].tolist()
    return point


#: Backends that evaluate Stan's log density for the check: the native driver's
#: ``--log-density`` mode (default: the program compiled once for sampling serves the
#: check) and PyStan's ``log_prob`` (the oracle of the tests).
CHECK_BACKENDS = ("native", "pystan")


@dataclass
class StanDensity:
    """Stan's log density of one program with one data set: the model block without
    Jacobian, at constrained points; None where Stan rejects a point (outside its bounds,
    or a constraint of the program fails)."""

    param_names: list[str]
    dims: list[list[int]]
    evaluate: Callable[[list[dict]], list[float | None]]

    def at(self, point: dict) -> float | None:
        return self.evaluate([point])[0]


@contextmanager
def stan_density(stan_path: Path, data: dict, backend: str = "native") -> Iterator[StanDensity]:
    """Build the program for ``data`` with ``backend`` (one of :data:`CHECK_BACKENDS`).

    ValueError when the program rejects the data (or cannot be built for them)."""
    if backend == "native":
        from .stan_backends.base import BackendError
        from .stan_backends.native import NativeBackend

        native = NativeBackend()
        try:
            head = native.log_density(stan_path, data, [])
        except BackendError:
            raise
        except RuntimeError as err:  # stanc or the compiler rejects the program
            raise ValueError(str(err)) from err

        def native_values(points: list[dict]) -> list[float | None]:
            return native.log_density(stan_path, data, points).values

        yield StanDensity(head.param_names, head.dims, native_values)
    elif backend == "pystan":
        import stan

        from .stan_backends.pystan import PyStanBackend

        with PyStanBackend().session(stan_path):
            try:
                # mypy resolves `stan` to the repository's stan/ folder (pystan has no stubs)
                post = stan.build(stan_path.read_text(), data=data)  # type: ignore[attr-defined]
            except Exception as err:  # noqa: BLE001 - PyStan raises bare exceptions
                raise ValueError(f"{type(err).__name__}: {err}") from err

            def pystan_values(points: list[dict]) -> list[float | None]:
                out: list[float | None] = []
                for point in points:
                    try:
                        value = post.log_prob(post.unconstrain_pars(point), adjust_transform=False)
                    except RuntimeError:
                        out.append(None)
                        continue
                    out.append(float(value) if np.isfinite(value) else None)
                return out

            yield StanDensity(list(post.param_names), [list(d) for d in post.dims], pystan_values)
    else:
        raise ValueError(f"check backend {backend!r}: allowed {list(CHECK_BACKENDS)}")


def _fmt(omega: np.ndarray, names: Sequence[str]) -> str:
    return ", ".join(f"{n}={v:.6g}" for n, v in zip(names, omega))


def _locate_difference(
    model: StateSpaceModel,
    stan_path: Path,
    density: StanDensity,
    theta: np.ndarray,
    z: np.ndarray,
    bounds: Any,
    rng: np.random.Generator,
    rtol: float,
    backend: str,
) -> str:
    """Which block of Theta (Omega and its components, x0, x_1..x_T) and which term of the
    log posterior (2) a difference Stan - Python depends on: change one block (or the data
    z) at a time from a base point and see whether the difference moves."""
    T = z.shape[0]
    m, p = model.n_params, model.state_dim
    base = theta[0]

    def gap(point: np.ndarray, dens: StanDensity = density, z_: np.ndarray = z) -> float | None:
        s = dens.at(_stan_point(model, point, T))
        return None if s is None else s - float(log_posterior(model, point, z_, bounds))

    ref = gap(base)
    if ref is None:
        return "Stan rejects the base point"

    def moves(point: np.ndarray, dens: StanDensity = density, z_: np.ndarray = z) -> bool:
        g = gap(point, dens, z_)
        return g is not None and abs(g - ref) > rtol * max(1.0, abs(ref)) * 10

    changed = []
    for j, name in enumerate(model.param_names):
        point = base.copy()
        point[j] = theta[1, j]
        if in_support(model, point[None, :m], bounds)[0] and moves(point):
            changed.append(name)
    point = base.copy()
    point[m : m + p] += 0.3
    x0_moves = moves(point)
    point = base.copy()
    point[m + p :] += rng.normal(0.0, 0.3, size=point.size - m - p)
    x_moves = moves(point)
    z2 = z + rng.normal(0.0, 0.3, size=z.shape)
    with stan_density(stan_path, model.stan_data(z2, bounds), backend) as density2:
        z_moves = moves(base, density2, z2)
    blocks = [f"Omega ({', '.join(changed)})"] if changed else []
    blocks += ["x0"] * x0_moves + ["x_1..x_T"] * x_moves + ["the data z"] * z_moves
    if z_moves:
        term = "the observation term (the only one with z)"
    elif x0_moves:
        term = "the transition term at t = 1 or the initial state's prior"
    elif x_moves:
        term = "the transition term (the states move it, the data do not)"
    elif changed:
        term = "the prior of Omega or a normalising term in Omega alone (e.g. log(1 - a^2))"
    else:
        return "no single block moves the difference alone"
    return f"the difference moves with {', '.join(blocks)}: look at {term}"


def stan_problems(
    model: StateSpaceModel,
    stan_path: Path,
    case: CheckCase,
    T: int = 6,
    n_points: int = 6,
    seed: int = 0,
    rtol: float = 1e-8,
    backend: str = "native",
) -> list[str]:
    """Compiled Stan against Python for one case: names, shapes, log density, support."""
    problems: list[str] = []
    rng = np.random.default_rng(seed)
    theta, z, bounds = _sample_theta(model, case, T, n_points, rng)
    data = model.stan_data(z, bounds)
    names = model.param_names
    where = f"({case.label()})"
    with ExitStack() as stack:
        try:
            density = stack.enter_context(stan_density(stan_path, data, backend))
        except ValueError as err:
            return [
                f"{stan_path.name}: building the program with the Python model's data "
                f"failed {where} (the program rejects the data): {err}"
            ]
        want = expected_parameters(model)
        if density.param_names != want:
            return [
                f"{stan_path.name}: compiled parameters are {density.param_names}, the Python "
                f"model needs {want} in this order"
            ]
        p = model.state_dim
        dims = dict(zip(density.param_names, density.dims))
        want_dims = {
            **{n: [] for n in names},
            "x0": [] if p == 1 else [p],
            "x": [T] if p == 1 else [T, p],
        }
        bad = {k: (dims[k], v) for k, v in want_dims.items() if list(dims[k]) != v}
        if bad:
            return [f"{stan_path.name}: parameter shapes (Stan, expected) {bad} for T={T}, p={p}"]
        # log density inside the support: equal up to one additive constant
        py = np.array([float(log_posterior(model, th, z, bounds)) for th in theta])
        st = density.evaluate([_stan_point(model, th, T) for th in theta])
        for th, s in zip(theta, st):
            if s is None:
                problems.append(
                    f"{stan_path.name}: Stan rejects {_fmt(th, names)}, which is "
                    f"inside the Python model's support {where}; the bounds in "
                    f"Stan are narrower than the Python prior"
                )
        if problems:
            return problems
        diff = np.array(st, dtype=float) - py
        scale = np.maximum(1.0, np.abs(py))
        off = np.abs(diff - diff[0]) / scale
        if off.max() > rtol:
            i = int(off.argmax())
            problems.append(
                f"{stan_path.name}: log density differs from the Python log posterior by more "
                f"than a constant {where}: Stan - Python = {diff[0]:.10g} at "
                f"{_fmt(theta[0], names)}"
                f" but {diff[i]:.10g} at {_fmt(theta[i], names)} (states as well differ); "
                + _locate_difference(
                    model, stan_path, density, theta, z, bounds, rng, rtol, backend
                )
            )
            return problems
        const = diff[0]
        # support: just inside / just outside every finite prior bound, and model constraints
        base = theta[0].copy()
        for j, name in enumerate(names):
            for side, bound in (("lower", bounds.lower[j]), ("upper", bounds.upper[j])):
                if not np.isfinite(bound):
                    continue
                step = 1e-3 * max(1.0, abs(bound))
                sign = 1.0 if side == "lower" else -1.0
                inside, outside = base.copy(), base.copy()
                inside[j] = bound + sign * step
                outside[j] = bound - sign * step
                s_in, s_out = density.evaluate(
                    [_stan_point(model, inside, T), _stan_point(model, outside, T)]
                )
                if in_support(model, inside[None, : model.n_params], bounds)[0]:
                    if s_in is None:
                        problems.append(
                            f"{stan_path.name}: Stan rejects {name}={inside[j]:.6g}, just inside "
                            f"the Python prior's {side} bound {bound:g} {where}; declare "
                            f"<lower={name}_lower, upper={name}_upper> on {name}"
                        )
                    elif (
                        abs(s_in - float(log_posterior(model, inside, z, bounds)) - const)
                        > rtol * max(1.0, abs(s_in)) * 10
                    ):
                        problems.append(
                            f"{stan_path.name}: log density differs by more than a "
                            f"constant at {name}={inside[j]:.6g} {where}"
                        )
                if s_out is not None:
                    problems.append(
                        f"{stan_path.name}: Stan accepts {name}={outside[j]:.6g} (log density "
                        f"{s_out:.6g}), outside the Python prior's {side} bound {bound:g} "
                        f"('{bounds.variants[j]}' {where}); Stan does not share this prior "
                        f"bound: declare <lower={name}_lower, upper={name}_upper> on {name}"
                    )
        # points of the prior box that violate a model constraint must be rejected by Stan
        lo = np.where(np.isfinite(bounds.lower), bounds.lower, -3.0)
        hi = np.where(np.isfinite(bounds.upper), bounds.upper, 3.0)
        cand = lo + (hi - lo) * rng.uniform(0.01, 0.99, size=(400, model.n_params))
        violating = cand[~in_support(model, cand, bounds)][:3]
        points = [np.concatenate([om, base[model.n_params :]]) for om in violating]
        for om, s in zip(violating, density.evaluate([_stan_point(model, pt, T) for pt in points])):
            if s is not None:
                problems.append(
                    f"{stan_path.name}: Stan accepts {_fmt(om, names)}, which "
                    f"violates a support constraint of the Python model "
                    f"({', '.join(model.constraint_text) or 'support_constraints'})"
                )
        return problems


# ----------------------------------------------------------------------------- driver
def check_model(
    slug: str,
    cases: Sequence[CheckCase] | None = None,
    stan: bool = True,
    stan_path: str | Path | None = None,
    T: int = 6,
    seed: int | None = None,
    backend: str = "native",
) -> CheckReport:
    """Every check of this module for one model; the report lists each problem found.

    ``cases`` default to :func:`default_cases`; ``stan=False`` skips the Stan checks (for a
    config that never runs Stan for this model).  Checks stop at the first stage, and within
    it at the first case, with problems, so that one mistake gives one message.
    """
    from .stan_backends import stan_file

    model = get_model(slug)
    report = CheckReport(slug)
    cases = list(cases) if cases else default_cases(model)
    seed = zlib.crc32(slug.encode()) if seed is None else seed
    found: list[str] = []
    for i, case in enumerate(cases):
        problems = model.check_true_values(case.omega, case.x0, case.prior)
        if not problems:
            problems = python_problems(model, case, T=T, seed=seed + i)
        if not problems:
            problems = simulate_problems(model, case, T=T, seed=seed + i)
        found = [f"[python, {case.label()}] {p}" for p in problems]
        if found:  # the same mistake shows in every case: report the first
            break
    report.record(
        f"python: simulator shapes, initial_states, gradient and Hessian vs finite "
        f"differences, simulated disturbances recovered by the terms ({len(cases)} case(s))",
        found,
    )
    if report.problems or not stan:
        return report
    path = Path(stan_path) if stan_path is not None else stan_file(slug)
    report.record(
        f"stan source {path.name}: parameter names/order, data declarations",
        stan_source_problems(model, path),
    )
    if report.problems:
        return report
    for i, case in enumerate(cases):
        found = stan_problems(model, path, case, T=T, seed=seed + i, backend=backend)
        if found:
            break
    report.record(
        f"stan compiled: names, shapes, log density up to a constant, support "
        f"bounds ({len(cases)} case(s))",
        found,
    )
    return report


def run_check_model(
    slug: str,
    scenarios: Sequence[Mapping[str, Any]],
    out: str | Path,
    stan: bool = True,
    stan_path: str | Path | None = None,
) -> CheckReport:
    """Rule check_model: check the model for the default cases and the true values of every
    configured case under every prior variant (:func:`prior_variant_cases`); write the
    report; raise :class:`ModelCheckError` listing every problem."""
    model = get_model(slug)
    cases = default_cases(model)
    for scenario_case in cases_from_scenarios(scenarios, slug):
        for case in prior_variant_cases(model, scenario_case):
            if case not in cases:
                cases.append(case)
    report = check_model(slug, cases, stan=stan, stan_path=stan_path)
    if report.problems:
        raise ModelCheckError(
            f"model '{slug}': the Python model and the Stan program "
            f"disagree:\n  - " + "\n  - ".join(report.problems)
        )
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    Path(out).write_text(json.dumps(report.to_dict(), indent=2) + "\n")
    return report


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m ssmobs.check_model",
        description="Check workflow/ssmobs/models/<slug>.py against stan/<slug>.stan.",
    )
    parser.add_argument("slug", help="model slug (the file name of the model module)")
    parser.add_argument(
        "--configfile",
        help="also check every (omega, x0, prior) of this config's scenarios of the model",
    )
    parser.add_argument("--no-stan", action="store_true", help="Python checks only")
    parser.add_argument(
        "--backend",
        choices=CHECK_BACKENDS,
        default="native",
        help="what evaluates Stan's log density (default: the native driver)",
    )
    args = parser.parse_args(argv)
    try:
        model = get_model(args.slug)
    except ValueError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    cases = default_cases(model)
    if args.configfile:
        from .config import ConfigError, read_config_file, validate

        try:
            config = validate(read_config_file(args.configfile))
        except ConfigError as err:
            print(f"error: {err}", file=sys.stderr)
            return 2
        cases += [c for c in cases_from_scenarios(config["scenarios"], args.slug) if c not in cases]
    report = check_model(args.slug, cases, stan=not args.no_stan, backend=args.backend)
    for line in report.checks:
        print(f"checked  {line}")
    if report.problems:
        print(f"failed   {report.failed}", file=sys.stderr)
        print(f"model '{args.slug}': {len(report.problems)} problem(s):", file=sys.stderr)
        for p in report.problems:
            print(f"  - {p}", file=sys.stderr)
        return 1
    print(f"model '{args.slug}': Python model and Stan program agree")
    return 0


if __name__ == "__main__":
    sys.exit(main())
