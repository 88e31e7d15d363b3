"""Whether a model's posterior can be normalised, decided from its terms (issue 60).

The prior on Omega is flat on a box and x0 is flat on the whole line (Sec. IV), so the
posterior is proper only if the likelihood integrates.  Two findings make it improper:

1. **an orbit of infinite mass**: a symmetry of infinite order
   (:mod:`ssmobs.models.symmetries`) leaves the density unchanged along an unbounded orbit.
   A translation x -> x + P moves x0, flat on the line, without bound: improper for every
   prior.  A ridge v = sum_b (alpha_b theta_b + beta_b) d/dtheta_b maps volume by e^(delta s),
   delta = sum of alpha over Theta's coordinates; its orbit through Theta stays in the prior
   box for s in an interval (s_lo, s_hi), and the posterior is improper when
   int e^(delta s) ds over it is infinite (s_hi = inf with delta >= 0, or s_lo = -inf with
   delta <= 0), for every T >= 1.
2. **a flat variable that drops out**: component j of x0 leaves the likelihood where no
   state coordinate it reaches is observed.  Coordinate k is observed unless
   d obs_term / d x_k vanishes identically in (x, z); x_{t-1, j} reaches x_{t, k} unless
   d^2 trans_term / d x_{t-1, j} d x_{t, k} does (for the first step, unless d trans_term /
   d x_{t-1, j} vanishes identically in (x_{t-1}, x_t)).  The parameter values where it
   happens are solved for with SymPy (coefficients of the numerator as a polynomial in the
   states, the data and the functions of them).  A set {Omega_i = v} strictly inside the
   prior box makes the marginal posterior diverge there (improper); at an end of the prior
   interval it is the paper's documented edge (``edge``: numbers stay, a note is shown).
   A set of two or more equations on the boundary of the box is a ``note``; strictly inside
   it, or where SymPy cannot solve, it is ``undetermined``.

docs/method/symmetries.md and docs/method/improper-posteriors.md explain both rules and what
they cannot find.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field

import numpy as np
import sympy as sp

from .base import PriorBounds, StateSpaceModel
from .symmetries import Ridge, model_symbols, model_symmetries, preserves_box, x0_names

#: the horizons at which a ridge's volume factor e^(delta s) is judged (it grows with T
#: when the ridge scales the states)
_HORIZONS = (1, 10_000)


@dataclass(frozen=True)
class DropOut:
    """Component ``variable`` of x0 leaves the likelihood where ``condition`` holds."""

    variable: str
    condition: tuple[tuple[str, sp.Expr], ...]  # (parameter, value) pairs, all holding

    @property
    def text(self) -> str:
        return " and ".join(f"{name} = {sp.sstr(value)}" for name, value in self.condition)


@dataclass(frozen=True)
class ModelDropOuts:
    """Every drop-out set found, and the ones SymPy could not decide (as readable text)."""

    sets: tuple[DropOut, ...]
    undetermined: tuple[str, ...] = ()


@dataclass(frozen=True)
class Propriety:
    """Reasons the posterior is improper inside the prior support (``improper``), the same
    drop-out at an end of the support (``edge``), what could not be decided
    (``undetermined``), and drop-outs of codimension two or more on the boundary of the box
    (``notes``, for the model check); all empty when nothing is found."""

    improper: tuple[str, ...]
    edge: tuple[str, ...]
    undetermined: tuple[str, ...] = field(default=())
    notes: tuple[str, ...] = field(default=())

    @property
    def is_improper(self) -> bool:
        return bool(self.improper)

    def label(self) -> str:
        """ "" when proper, else "improper: <reason>; <reason>" (the words a table shows)."""
        return "improper: " + "; ".join(self.improper) if self.improper else ""


# ----------------------------------------------------------------------------- drop-outs
def _vanishing_sets(
    exprs: list[sp.Expr], variables: list[sp.Symbol], params: list[sp.Symbol]
) -> list[dict[sp.Symbol, sp.Expr]] | None:
    """Parameter values where every expression vanishes identically in ``variables``: the
    numerators' coefficients as polynomials in the variables and in each function of them,
    solved with SymPy; [] when there are none, None when SymPy cannot decide."""
    equations: list[sp.Expr] = []
    for expr in exprs:
        numer = sp.numer(sp.together(sp.expand(expr)))
        if numer == 0:
            continue
        atoms = sorted(
            (a for a in numer.atoms(sp.Function, sp.Pow) if a.free_symbols & set(variables)),
            key=sp.default_sort_key,
        )
        gens = list(variables)
        for atom in atoms:
            if isinstance(atom, sp.Pow) and atom.exp.is_Integer and atom.exp > 0:
                continue  # a polynomial power
            gens.append(atom)
        try:
            poly = sp.Poly(numer, *gens)
        except sp.PolynomialError:
            return None
        coeffs = poly.coeffs()
        if any(c.free_symbols & set(variables) for c in coeffs):
            return None
        equations.extend(coeffs)
    if not equations:
        return [{}]
    if any(e.is_number and e != 0 for e in equations):
        return []
    try:
        solutions = sp.solve(equations, params, dict=True)
    except (NotImplementedError, ValueError, TypeError):
        return None
    kept = []
    for sol in solutions:  # each must really make every expression vanish, inside the domain
        lefts = [sp.simplify(expr.subs(sol)) for expr in exprs]
        if any(v.has(sp.zoo, sp.nan, sp.oo, -sp.oo) for v in lefts):
            continue  # a denominator vanishes: outside the model's domain
        if any(v != 0 for v in lefts):
            return None
        kept.append(sol)
    return kept


def _dropout_systems(model: StateSpaceModel) -> list[tuple[int, list[sp.Expr], set[int]]]:
    """(j, expressions that must vanish, unobserved set U) for each x0 component j and each
    set U of state coordinates closed under the coupling from j (see the module docstring)."""
    syms = model_symbols(model)
    p = model.state_dim
    obs_d = [sp.diff(syms.obs, xk) for xk in syms.x]
    first = [sp.diff(syms.trans, xpj) for xpj in syms.xp]
    cross = [[sp.diff(first[j], syms.x[k]) for k in range(p)] for j in range(p)]
    systems = []
    for j in range(p):
        for size in range(p + 1):
            for chosen in itertools.combinations(range(p), size):
                unseen = set(chosen)
                if not unseen:
                    systems.append((j, [first[j]], unseen))
                    continue
                exprs = [obs_d[k] for k in sorted(unseen)]
                for u in sorted(unseen | {j}):
                    exprs += [cross[u][k] for k in range(p) if k not in unseen]
                systems.append((j, exprs, unseen))
    return systems


def _linear_dropouts(model: StateSpaceModel) -> list[DropOut] | None:
    """Where a direction of x0 drops out of a model that is linear and Gaussian in the states
    (second derivatives of the terms free of states and data), else None.

    With trans = (x - F x_prev)' Q^-1 (x - F x_prev) + ... and obs = (z - H x)' R^-1 (z - H x)
    + ..., F = -(d^2 trans / dx dx)^-1 d^2 trans / dx dx_prev and R^-1 H = -d^2 obs / dz dx / 2:
    a direction u of x0 leaves the likelihood where H F^t u = 0 for t = 1..p, i.e. where
    every p x p minor of the observability matrix [H F; ...; H F^p] vanishes; its
    codimension-1 part is the zero set of the minors' greatest common divisor, factored."""
    syms = model_symbols(model)
    p = model.state_dim
    state_data = set(syms.xp + syms.x + syms.z)
    hxx = sp.Matrix(p, p, lambda k, i: sp.diff(syms.trans, syms.x[k], syms.x[i]))
    hxp = sp.Matrix(p, p, lambda k, j: sp.diff(syms.trans, syms.x[k], syms.xp[j]))
    hzx = sp.Matrix(model.obs_dim, p, lambda i, k: sp.diff(syms.obs, syms.z[i], syms.x[k]))
    if any(e.free_symbols & state_data for e in (*hxx, *hxp, *hzx)):
        return None
    try:
        F = sp.simplify(-hxx.inv() * hxp)
    except (ValueError, ZeroDivisionError, sp.matrices.common.NonInvertibleMatrixError):
        return None
    rows = [hzx * F**t for t in range(1, p + 1)]
    obs_matrix = sp.Matrix.vstack(*rows)
    minors = [
        sp.numer(sp.together(obs_matrix.extract(list(r), list(range(p))).det()))
        for r in itertools.combinations(range(obs_matrix.rows), p)
    ]
    minors = [sp.expand(mn) for mn in minors if sp.expand(mn) != 0]
    if not minors:
        return [DropOut("a direction of x0", ())]
    common = minors[0]
    for mn in minors[1:]:
        common = sp.gcd(common, mn)
    out: list[DropOut] = []
    for factor, _ in sp.factor_list(common)[1]:
        params = [w for w in syms.w if factor.has(w)]
        linear = [w for w in params if sp.degree(factor, w) == 1]
        if not linear:
            continue
        target = linear[0]
        for value in sp.solve(factor, target):
            name = model.param_names[syms.w.index(target)]
            value = value.xreplace(dict(zip(syms.w, sp.symbols(model.param_names, real=True))))
            out.append(DropOut("a direction of x0" if p > 1 else "x0", ((name, value),)))
    return out


_DROPOUT_MEMO: dict[type, ModelDropOuts] = {}


def model_dropouts(model: StateSpaceModel) -> ModelDropOuts:
    """Where each component of x0 drops out of the likelihood (memoised per model class)."""
    key = type(model)
    if key in _DROPOUT_MEMO:
        return _DROPOUT_MEMO[key]
    syms = model_symbols(model)
    names = x0_names(model)
    variables = syms.xp + syms.x + syms.z
    named = dict(zip(syms.w, sp.symbols(model.param_names, real=True)))
    found: list[DropOut] = []
    undetermined: list[str] = []
    for j, exprs, _unseen in _dropout_systems(model):
        solutions = _vanishing_sets(exprs, variables, syms.w)
        if solutions is None:
            undetermined.append(
                f"whether {names[j]} drops out of the likelihood (SymPy could not solve for "
                f"the parameter values): not determined"
            )
            continue
        for sol in solutions:
            cond = tuple(
                sorted(
                    (
                        (model.param_names[syms.w.index(s)], sp.nsimplify(v).xreplace(named))
                        for s, v in sol.items()
                    ),
                    key=lambda c: c[0],
                )
            )
            item = DropOut(names[j], cond)
            if item not in found:
                found.append(item)
    for item in _linear_dropouts(model) or []:
        if not any(d.condition == item.condition for d in found):
            found.append(item)
    # a set implied by a smaller one of the same variable adds nothing
    minimal = [
        d
        for d in found
        if not any(
            o is not d and o.variable == d.variable and set(o.condition) < set(d.condition)
            for o in found
        )
    ]
    # in a fixed, readable order: x0's components, then directions; parameters in order
    minimal.sort(
        key=lambda d: (
            d.variable.startswith("a direction"),
            d.variable,
            [model.param_names.index(name) for name, _ in d.condition],
        )
    )
    result = ModelDropOuts(tuple(minimal), tuple(dict.fromkeys(undetermined)))
    _DROPOUT_MEMO[key] = result
    return result


def _interval_text(lo: float, hi: float) -> str:
    return f"({lo:g}, {hi:g})"


def _judge_dropout(
    model: StateSpaceModel, item: DropOut, bounds: PriorBounds
) -> tuple[str, str] | None:
    """("improper" | "edge" | "undetermined" | "note", reason) of one drop-out set under ``bounds``,
    or None when it lies outside the prior box."""
    if not item.condition:
        return (
            "improper",
            f"{item.variable} never enters the likelihood and is flat on the line",
        )
    if len(item.condition) > 1:
        return _judge_high_codimension(model, item, bounds)
    ((name, value),) = item.condition
    i = model.param_names.index(name)
    lo, hi = float(bounds.lower[i]), float(bounds.upper[i])
    where = f"prior {_interval_text(lo, hi)} of {name}"
    if value.free_symbols:
        if _relation_inside(model, name, value, bounds):
            return (
                "improper",
                f"{item.variable} drops out of the likelihood where {item.text}, inside the "
                f"prior: the marginal posterior diverges there",
            )
        return None
    if not value.is_real:
        return None
    v = float(value)
    if lo < v < hi:
        return (
            "improper",
            f"{item.variable} drops out of the likelihood at {item.text}, inside the {where}: "
            f"the marginal posterior diverges there",
        )
    if v in (lo, hi):
        return (
            "edge",
            f"{name} -> {v:g}: {item.variable} drops out of the likelihood at the end of the "
            f"{where}",
        )
    return None


def _judge_high_codimension(
    model: StateSpaceModel, item: DropOut, bounds: PriorBounds
) -> tuple[str, str] | None:
    """A drop-out set of two or more equations: outside the closed prior box, nothing; on
    its boundary (some parameter at an end of its interval), a ``note`` (the model check
    shows it; the tables do not: a corner like a = b = 0 is not one of the documented
    improper ends); strictly
    inside, or not decidable here, ``undetermined`` (whether the marginal is integrable
    across a set of codimension two or more depends on how fast it diverges)."""
    codim = len(item.condition)
    values: list[tuple[float, float, float]] = []
    for name, value in item.condition:
        if value.free_symbols or not value.is_real:
            values = []
            break
        i = model.param_names.index(name)
        values.append((float(value), float(bounds.lower[i]), float(bounds.upper[i])))
    if values:
        if any(not lo <= v <= hi for v, lo, hi in values):
            return None
        if any(v in (lo, hi) for v, lo, hi in values):
            return (
                "note",
                f"{item.text}: {item.variable} drops out of the likelihood at the edge of the "
                f"prior box (a set of codimension {codim})",
            )
    return (
        "undetermined",
        f"{item.variable} drops out of the likelihood where {item.text} (a set of "
        f"codimension {codim}): whether the posterior is proper there is not determined",
    )


def _relation_inside(
    model: StateSpaceModel, name: str, value: sp.Expr, bounds: PriorBounds
) -> bool:
    """Whether {name = value(other parameters)} meets the inside of the prior box and the
    model constraints, judged at 4000 random points of the box (a fixed seed)."""
    from .log_posterior import in_support

    rng = np.random.default_rng(60)
    lo = np.where(np.isfinite(bounds.lower), bounds.lower, np.minimum(bounds.upper, 0.0) - 10.0)
    hi = np.where(np.isfinite(bounds.upper), bounds.upper, np.maximum(bounds.lower, 0.0) + 10.0)
    pts = lo + (hi - lo) * rng.uniform(0.001, 0.999, size=(4000, model.n_params))
    i = model.param_names.index(name)
    symbols = sp.symbols(model.param_names, real=True)
    func = sp.lambdify(symbols, value, modules="numpy")
    with np.errstate(all="ignore"):
        pts[:, i] = np.broadcast_to(np.asarray(func(*pts.T), dtype=float), (pts.shape[0],))
    return bool(np.any(in_support(model, pts, bounds)))


def _ridge_improper(model: StateSpaceModel, ridge: Ridge, bounds: PriorBounds) -> bool:
    """Whether the ridge's orbits have infinite mass inside the prior box (module docstring)."""
    m, p = model.n_params, model.state_dim
    alpha = np.asarray(ridge.scaling)
    beta = np.asarray(ridge.translation)
    # the orbit of a parameter stays in (lo, hi) for s in an interval; find whether it is
    # unbounded above / below for every starting point inside the box
    up, down = True, True
    for i in range(m):
        a, b, lo, hi = alpha[i], beta[i], bounds.lower[i], bounds.upper[i]
        if a == 0 and b == 0:
            continue
        if a == 0:  # theta + b s
            up &= (hi == math.inf) if b > 0 else (lo == -math.inf)
            down &= (lo == -math.inf) if b > 0 else (hi == math.inf)
            continue
        # (theta + c) e^(a s) - c with c = b / a: the fixed point -c; theta moves away from
        # it as a s grows and towards it as a s falls
        c = b / a
        away_ok = (hi <= -c or hi == math.inf) and (lo >= -c or lo == -math.inf)
        towards_ok = lo <= -c <= hi  # approaching the fixed point stays in the box
        if a > 0:
            up &= away_ok
            down &= towards_ok
        else:
            down &= away_ok
            up &= towards_ok
    verdicts = []
    for T in _HORIZONS:
        delta = float(np.sum(alpha[:m]) + (T + 1) * np.sum(alpha[m : m + p]))
        verdicts.append((up and delta >= 0) or (down and delta <= 0))
    return all(verdicts)


_MEMO: dict[tuple, Propriety] = {}


def posterior_propriety(model: StateSpaceModel, bounds: PriorBounds) -> Propriety:
    """The propriety findings for the model under the flat prior ``bounds`` (memoised on
    the model class and the bounds)."""
    key = (type(model), tuple(map(float, bounds.lower)), tuple(map(float, bounds.upper)))
    if key in _MEMO:
        return _MEMO[key]
    improper: list[str] = []
    edge: list[str] = []
    undetermined: list[str] = []
    notes: list[str] = []
    syms = model_symmetries(model)
    for sym in syms.discrete:
        if sym.infinite_order and preserves_box(sym, bounds):
            improper.append(
                f"{sym.name} (x0 and every state together) leaves the density unchanged and "
                f"x0 is flat on the line"
            )
    for ridge in syms.ridges:
        if _ridge_improper(model, ridge, bounds):
            moved = (
                f" ({', '.join(ridge.unbounded)} flat on the line and moved without bound)"
                if ridge.unbounded
                else ""
            )
            improper.append(
                f"the ridge {ridge.name} leaves the density unchanged along orbits of infinite "
                f"mass inside the prior{moved}"
            )
    drops = model_dropouts(model)
    undetermined += drops.undetermined
    for item in drops.sets:
        judged = _judge_dropout(model, item, bounds)
        if judged is None:
            continue
        kind, reason = judged
        found = {"improper": improper, "edge": edge, "undetermined": undetermined, "note": notes}
        found[kind].append(reason)
    result = Propriety(
        improper=tuple(dict.fromkeys(improper)),
        edge=tuple(dict.fromkeys(edge)),
        undetermined=tuple(dict.fromkeys(undetermined)),
        notes=tuple(dict.fromkeys(notes)),
    )
    _MEMO[key] = result
    return result
