"""The compiled Stan program of the model check (:mod:`ssmobs.model_check.check`, step 3): its
parameter names and shapes, its log density against the Python one up to one additive
constant, and its support, evaluated by the native driver or PyStan (:func:`stan_density`).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..models import StateSpaceModel
from ..models.check_cases import CheckCase, sample_theta
from ..models.log_posterior import in_support, log_posterior
from ..stan_backends.base import program_code
from .stan_source import expected_parameters


def stan_point(model: StateSpaceModel, theta: np.ndarray, T: int) -> dict:
    """Theta = (Omega, x_0, x_1..x_T) as Stan's constrained values, by parameter name."""
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
def stan_density(
    stan_path: Path, data: dict, backend: str = "native", user_header: Path | None = None
) -> Iterator[StanDensity]:
    """Build the program for ``data`` with ``backend`` (one of :data:`CHECK_BACKENDS`);
    ``user_header``: the C++ of its external functions (a generated program; native only).

    ValueError when the program rejects the data (or cannot be built for them)."""
    if user_header is not None and backend != "native":
        raise ValueError(
            f"{stan_path.name} calls generated C++ (analytic gradients), which only the "
            f"native backend evaluates here; check backend {backend!r}"
        )
    if backend == "native":
        from ..stan_backends.base import BackendError
        from ..stan_backends.native import NativeBackend

        native = NativeBackend()
        try:
            head = native.log_density(stan_path, data, [], user_header)
        except BackendError:
            raise
        except RuntimeError as err:  # stanc or the compiler rejects the program
            raise ValueError(str(err)) from err

        def native_values(points: list[dict]) -> list[float | None]:
            return native.log_density(stan_path, data, points, user_header).values

        yield StanDensity(head.param_names, head.dims, native_values)
    elif backend == "pystan":
        import stan

        from ..stan_backends.pystan import PyStanBackend

        with PyStanBackend().session(stan_path):
            try:
                # mypy resolves `stan` to the repository's stan/ folder (pystan has no stubs)
                post = stan.build(program_code(stan_path), data=data)  # type: ignore[attr-defined]
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
    *,
    backend: str,
    user_header: Path | None = None,
) -> str:
    """Which block of Theta (Omega and its components, x0, x_1..x_T) and which term of the
    log posterior (2) a difference Stan - Python depends on: change one block (or the data
    z) at a time from a base point and see whether the difference moves."""
    T = z.shape[0]
    m, p = model.n_params, model.state_dim
    base = theta[0]

    def gap(point: np.ndarray, dens: StanDensity = density, z_: np.ndarray = z) -> float | None:
        s = dens.at(stan_point(model, point, T))
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
    with stan_density(stan_path, model.stan_data(z2, bounds), backend, user_header) as density2:
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
    *,
    T: int = 6,
    n_points: int = 6,
    seed: int = 0,
    rtol: float = 1e-8,
    backend: str = "native",
    user_header: Path | None = None,
) -> list[str]:
    """Compiled Stan against Python for one case: names, shapes, log density, support
    (``user_header``: the C++ a generated program calls, :func:`stan_density`)."""
    problems: list[str] = []
    rng = np.random.default_rng(seed)
    theta, z, bounds = sample_theta(model, case, T, n_points, rng)
    data = model.stan_data(z, bounds)
    names = model.param_names
    where = f"({case.label()})"
    with ExitStack() as stack:
        try:
            density = stack.enter_context(stan_density(stan_path, data, backend, user_header))
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
        st = density.evaluate([stan_point(model, th, T) for th in theta])
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
                    model,
                    stan_path,
                    density,
                    theta,
                    z,
                    bounds,
                    rng,
                    rtol,
                    backend=backend,
                    user_header=user_header,
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
                    [stan_point(model, inside, T), stan_point(model, outside, T)]
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
        for om, s in zip(violating, density.evaluate([stan_point(model, pt, T) for pt in points])):
            if s is not None:
                problems.append(
                    f"{stan_path.name}: Stan accepts {_fmt(om, names)}, which "
                    f"violates a support constraint of the Python model "
                    f"({', '.join(model.constraint_text) or 'support_constraints'})"
                )
        return problems
