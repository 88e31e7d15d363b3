"""The symmetries of a model's joint density, found from its SymPy terms (issue 60).

A map g of Theta = (Omega, x_0, x_1..x_T) is a symmetry of the model when
-2 log pi(g Theta | z) = -2 log pi(Theta | z) for every z (Sec. III.B: every maximum then has
g-images of the same height).  The search is over stated families only:

* **discrete maps**: each parameter Omega_i -> +-Omega_pi(i) (sign changes and permutations
  of the parameters), each state coordinate x_j -> +-x_sigma(j) + c_j at every time together
  (sign changes, permutations of state coordinates, translations c_j = P/2, P by the period
  P of a periodic function the coordinate enters, SymPy's ``periodicity``, and reflections
  x_j -> c_j - x_j with c_j = P/4, P/2, 3P/4), in all combinations;
* **ridges**: one-parameter flows of the generators
  v = sum_b (alpha_b theta_b + beta_b) d/dtheta_b, which scale and/or translate each block
  (each parameter; each state coordinate over x_0..x_T together).

A discrete candidate is accepted only when ``obs_term`` and ``trans_term`` are each unchanged
with z left symbolic (``sympy.simplify`` of the difference is 0), after a numeric screen and
before a numeric confirmation at fresh random points.  A map under which only the sum over t
is unchanged is not found.  A ridge is the null space of the linear conditions
grad(-2 log pi) . v = 0 at random (Theta, z), each basis generator confirmed by following its
curve (:mod:`ssmobs.models._ridges`; the terms as both searches use them:
:mod:`ssmobs.models._model_terms`).  docs/method/symmetries.md states the families and what
the search cannot find.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field

import numpy as np
import sympy as sp

from ._model_terms import (
    SEARCH_SEED,
    ModelTerms,
    model_symbols,
    random_points,
    split_blocks,
    state_names,
    term_values,
    x0_names,
)
from ._ridges import RIDGE_STRETCH, Ridge, ridges
from .base import PriorBounds, StateSpaceModel

__all__ = [
    "DiscreteSymmetry",
    "ModelSymmetries",
    "Ridge",
    "model_symbols",
    "model_symmetries",
    "preserves_box",
    "state_names",
    "x0_names",
]

#: random points of the numeric screen and of the numeric confirmation
SCREEN_POINTS = 12
CONFIRM_POINTS = 64
#: relative tolerance of a numeric equality of -2 log pi terms
NUMERIC_RTOL = 1e-8
#: at most this many discrete candidates are screened; beyond it parameter permutations are
#: limited to transpositions (documented in docs/method/symmetries.md)
MAX_CANDIDATES = 50_000


# ----------------------------------------------------------------------------- data types
@dataclass(frozen=True)
class DiscreteSymmetry:
    """Omega_i -> param_sign[i] * Omega_param_perm[i]; x_j -> state_sign[j] * x_state_perm[j]
    + state_shift[j] at every time t = 0..T."""

    name: str
    kind: str  # "sign" | "permutation" | "translation" | "reflection"
    infinite_order: bool
    param_sign: tuple[float, ...] = ()
    param_perm: tuple[int, ...] = ()
    state_sign: tuple[float, ...] = ()
    state_perm: tuple[int, ...] = ()
    state_shift: tuple[float, ...] = ()

    def apply(self, model: StateSpaceModel, theta: np.ndarray) -> np.ndarray:
        """Images of rows Theta = (Omega, x_0, x_1..x_T), shape (K, |Theta|)."""
        omega, states = split_blocks(model, theta)
        new_omega = np.asarray(self.param_sign) * omega[:, list(self.param_perm)]
        new_states = np.asarray(self.state_sign) * states[:, :, list(self.state_perm)] + np.asarray(
            self.state_shift
        )
        return np.concatenate([new_omega, new_states.reshape(theta.shape[0], -1)], axis=1)

    def apply_inverse(self, model: StateSpaceModel, theta: np.ndarray) -> np.ndarray:
        """The inverse map: y = s x[perm] + c  <=>  x[perm] = s (y - c)."""
        omega, states = split_blocks(model, theta)
        inv_w = np.argsort(self.param_perm)
        inv_x = np.argsort(self.state_perm)
        new_omega = (np.asarray(self.param_sign) * omega)[:, inv_w]
        shifted = np.asarray(self.state_sign) * (states - np.asarray(self.state_shift))
        new_states = shifted[:, :, inv_x]
        return np.concatenate([new_omega, new_states.reshape(theta.shape[0], -1)], axis=1)


def preserves_box(sym: DiscreteSymmetry, bounds: PriorBounds) -> bool:
    """Whether the map's action on Omega maps the prior box onto itself (so that the images
    of a point inside the support are inside it)."""
    lo, hi = np.asarray(bounds.lower, dtype=float), np.asarray(bounds.upper, dtype=float)
    sign, perm = np.asarray(sym.param_sign), list(sym.param_perm)
    new_lo = np.where(sign > 0, lo[perm], -hi[perm])
    new_hi = np.where(sign > 0, hi[perm], -lo[perm])
    return bool(np.array_equal(new_lo, lo) and np.array_equal(new_hi, hi))


@dataclass(frozen=True)
class ModelSymmetries:
    """The symmetries found for one model; ``unconfirmed`` names the candidates that passed
    the numeric screen but not the symbolic test (never used as symmetries; the model check
    shows them as warnings)."""

    discrete: tuple[DiscreteSymmetry, ...]
    ridges: tuple[Ridge, ...]
    unconfirmed: tuple[str, ...] = field(default=())

    def images(self, model: StateSpaceModel, theta: np.ndarray) -> list[np.ndarray]:
        """Every discrete map's image of the rows (translations in both directions)."""
        theta = np.asarray(theta, dtype=float)
        out: list[np.ndarray] = []
        for sym in self.discrete:
            out.append(sym.apply(model, theta))
            if sym.infinite_order:
                out.append(sym.apply_inverse(model, theta))
        return out

    def table(self) -> list[dict[str, str]]:
        """One row per symmetry: kind, name and how it was confirmed."""
        rows = [
            {
                "kind": s.kind + (" (infinite order)" if s.infinite_order else ""),
                "name": s.name,
                "confirmed": "obs_term and trans_term unchanged (sympy), and numerically at "
                f"{CONFIRM_POINTS} random points",
            }
            for s in self.discrete
        ]
        rows += [
            {
                "kind": "ridge",
                "name": r.name,
                "confirmed": "null direction of grad(-2 log pi) at every random point; density "
                f"constant along the curve for |s| <= {RIDGE_STRETCH:g}"
                + (f"; moves {', '.join(r.unbounded)} without bound" if r.unbounded else ""),
            }
            for r in self.ridges
        ]
        return rows


# ----------------------------------------------------------------------------- discrete maps
@dataclass(frozen=True)
class _Candidate:
    param_sign: tuple[float, ...]
    param_perm: tuple[int, ...]
    state_sign: tuple[float, ...]
    state_perm: tuple[int, ...]
    state_shift: tuple[sp.Expr, ...]

    def is_identity(self) -> bool:
        return (
            all(s == 1 for s in self.param_sign)
            and self.param_perm == tuple(range(len(self.param_perm)))
            and all(s == 1 for s in self.state_sign)
            and self.state_perm == tuple(range(len(self.state_perm)))
            and all(c == 0 for c in self.state_shift)
        )

    def numeric(
        self, w: np.ndarray, xp: np.ndarray, x: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        shift = np.array([float(c) for c in self.state_shift])
        sign = np.asarray(self.state_sign)
        perm = list(self.state_perm)
        return (
            np.asarray(self.param_sign) * w[:, list(self.param_perm)],
            sign * xp[:, perm] + shift,
            sign * x[:, perm] + shift,
        )

    def substitution(self, syms: ModelTerms) -> dict[sp.Symbol, sp.Expr]:
        sub: dict[sp.Symbol, sp.Expr] = {}
        for i, (s, k) in enumerate(zip(self.param_sign, self.param_perm)):
            sub[syms.w[i]] = int(s) * syms.w[k]
        for j, (s, k, c) in enumerate(zip(self.state_sign, self.state_perm, self.state_shift)):
            sub[syms.xp[j]] = int(s) * syms.xp[k] + c
            sub[syms.x[j]] = int(s) * syms.x[k] + c
        return sub


def state_periods(syms: ModelTerms) -> list[sp.Expr | None]:
    """Per state coordinate, the period of the periodic functions it enters (None if none):
    SymPy's ``periodicity`` of each function of the coordinate in either term; their least
    common multiple when it exists."""
    out: list[sp.Expr | None] = []
    for xj, xpj in zip(syms.x, syms.xp):
        periods = []
        for expr, var in ((syms.obs, xj), (syms.trans, xj), (syms.trans, xpj)):
            for atom in expr.atoms(sp.Function):
                if var in atom.free_symbols:
                    try:
                        per = sp.periodicity(atom, var)
                    except (NotImplementedError, ValueError, TypeError):
                        per = None
                    if per is not None and per.is_real and per.is_positive:
                        periods.append(per)
        period = None
        if periods:
            try:
                period = periods[0]
                for q in periods[1:]:
                    period = sp.lcm(period, q) if (period / q).is_rational else None
                    if period is None:
                        break
            except (TypeError, ValueError):
                period = None
        out.append(period)
    return out


def _state_options(period: sp.Expr | None) -> list[tuple[int, sp.Expr]]:
    """(sign, shift) options of one state coordinate."""
    options: list[tuple[int, sp.Expr]] = [(1, sp.S.Zero), (-1, sp.S.Zero)]
    if period is not None:
        options += [(1, period / 2), (1, period)]
        options += [(-1, period * k / 4) for k in (1, 2, 3)]
    return options


def _candidates(model: StateSpaceModel, periods: list[sp.Expr | None]) -> list[_Candidate]:
    m, p = model.n_params, model.state_dim
    state_opts = [_state_options(per) for per in periods]
    n_state = math.prod(len(o) for o in state_opts)
    param_perms = list(itertools.permutations(range(m)))
    if (2**m) * len(param_perms) * math.factorial(p) * n_state > MAX_CANDIDATES:
        ident = list(range(m))
        param_perms = [tuple(ident)]
        for i, k in itertools.combinations(range(m), 2):
            perm = ident.copy()
            perm[i], perm[k] = k, i
            param_perms.append(tuple(perm))
    out = []
    for signs in itertools.product((1.0, -1.0), repeat=m):
        for pperm in param_perms:
            for sperm in itertools.permutations(range(p)):
                for choice in itertools.product(*state_opts):
                    cand = _Candidate(
                        tuple(signs),
                        tuple(pperm),
                        tuple(float(s) for s, _ in choice),
                        tuple(sperm),
                        tuple(c for _, c in choice),
                    )
                    if not cand.is_identity():
                        out.append(cand)
    return out


def _equal(a: np.ndarray, b: np.ndarray) -> bool:
    return bool(
        np.all(np.isfinite(a)) and np.all(np.abs(a - b) <= NUMERIC_RTOL * (1.0 + np.abs(b)))
    )


def _numerically_invariant(
    cand: _Candidate, syms: ModelTerms, pts: tuple[np.ndarray, ...], base: tuple[np.ndarray, ...]
) -> bool:
    w, xp, x, z = pts
    w2, xp2, x2 = cand.numeric(w, xp, x)
    if not _equal(term_values(syms.obs_f, np.hstack([w2, x2, z])), base[0]):
        return False
    return _equal(term_values(syms.trans_f, np.hstack([w2, xp2, x2])), base[1])


def _symbolically_invariant(cand: _Candidate, syms: ModelTerms) -> bool:
    sub = cand.substitution(syms)
    for expr in (syms.obs, syms.trans):
        diff = expr.xreplace(sub) - expr
        if sp.expand(diff) != 0 and sp.simplify(diff) != 0:
            return False
    return True


def _fmt(value: sp.Expr) -> str:
    return sp.sstr(sp.nsimplify(value))


def _describe(model: StateSpaceModel, cand: _Candidate) -> tuple[str, str]:
    """(name, kind) of an accepted map."""
    pn, xn = list(model.param_names), state_names(model)
    moved_from, moved_to = [], []
    for i, (s, k) in enumerate(zip(cand.param_sign, cand.param_perm)):
        if s != 1 or k != i:
            moved_from.append(pn[i])
            moved_to.append(("-" if s < 0 else "") + pn[k])
    for j, (s, k, c) in enumerate(zip(cand.state_sign, cand.state_perm, cand.state_shift)):
        if s != 1 or k != j or c != 0:
            moved_from.append(xn[j])
            core = xn[k]
            if c == 0:
                moved_to.append(("-" if s < 0 else "") + core)
            elif s < 0:
                moved_to.append(f"{_fmt(c)} - {core}")
            else:
                moved_to.append(f"{core} + {_fmt(c)}")
    reflection = any(s < 0 and c != 0 for s, c in zip(cand.state_sign, cand.state_shift))
    translation = any(s > 0 and c != 0 for s, c in zip(cand.state_sign, cand.state_shift))
    permuted = cand.param_perm != tuple(range(model.n_params)) or cand.state_perm != tuple(
        range(model.state_dim)
    )
    kind = (
        "translation"
        if translation
        else "reflection"
        if reflection
        else "permutation"
        if permuted
        else "sign"
    )
    signs = all(s == 1 for s in cand.param_sign + cand.state_sign)
    if kind == "permutation" and signs:
        param_pairs = _transpositions(cand.param_perm, pn)
        state_pairs = _transpositions(cand.state_perm, xn)
        pairs = None if param_pairs is None or state_pairs is None else param_pairs + state_pairs
        if pairs:
            left = ", ".join(a for a, _ in pairs)
            right = ", ".join(b for _, b in pairs)
            if len(pairs) == 1:
                return f"swap {left} <-> {right}", kind
            return f"swap ({left}) <-> ({right})", kind
    if len(moved_from) == 1:
        return f"{moved_from[0]} -> {moved_to[0]}", kind
    return f"({', '.join(moved_from)}) -> ({', '.join(moved_to)})", kind


def _transpositions(perm: tuple[int, ...], names: list[str]) -> list[tuple[str, str]] | None:
    """The pairs of a permutation made of disjoint transpositions, else None."""
    pairs = []
    for i, k in enumerate(perm):
        if perm[k] != i:
            return None
        if i < k:
            pairs.append((names[i], names[k]))
    return pairs


def _infinite_order(model: StateSpaceModel, cand: _Candidate) -> bool:
    """True when no power g^k (k <= 48) of the map is the identity (a translation)."""
    sym = DiscreteSymmetry(
        "",
        "",
        False,
        cand.param_sign,
        cand.param_perm,
        cand.state_sign,
        cand.state_perm,
        tuple(float(c) for c in cand.state_shift),
    )
    start = np.random.default_rng(SEARCH_SEED).normal(size=(1, model.n_theta(2)))
    cur = start
    for _ in range(48):
        cur = sym.apply(model, cur)
        if np.allclose(cur, start, rtol=1e-12, atol=1e-9):
            return False
    return True


def discrete_symmetries(
    model: StateSpaceModel, syms: ModelTerms, rng: np.random.Generator
) -> tuple[list[DiscreteSymmetry], list[str]]:
    """The accepted discrete maps, and the names of those only numerics found."""
    screen = random_points(model, syms, rng, SCREEN_POINTS)
    confirm = random_points(model, syms, rng, CONFIRM_POINTS)
    if min(screen[0].shape[0], confirm[0].shape[0]) < SCREEN_POINTS // 2:
        return [], ["no discrete map tested: too few random points where the terms are finite"]

    def base(pts: tuple[np.ndarray, ...]) -> tuple[np.ndarray, np.ndarray]:
        w, xp, x, z = pts
        return (
            term_values(syms.obs_f, np.hstack([w, x, z])),
            term_values(syms.trans_f, np.hstack([w, xp, x])),
        )

    screen_base, confirm_base = base(screen), base(confirm)
    found: list[DiscreteSymmetry] = []
    unconfirmed: list[str] = []
    for cand in _candidates(model, state_periods(syms)):
        if not _numerically_invariant(cand, syms, screen, screen_base):
            continue
        name, kind = _describe(model, cand)
        if not _symbolically_invariant(cand, syms):
            unconfirmed.append(name)
            continue
        if not _numerically_invariant(cand, syms, confirm, confirm_base):
            continue
        found.append(
            DiscreteSymmetry(
                name=name,
                kind=kind,
                infinite_order=_infinite_order(model, cand),
                param_sign=cand.param_sign,
                param_perm=cand.param_perm,
                state_sign=cand.state_sign,
                state_perm=cand.state_perm,
                state_shift=tuple(float(c) for c in cand.state_shift),
            )
        )
    return found, unconfirmed


# ----------------------------------------------------------------------------- entry point
_MEMO: dict[type, ModelSymmetries] = {}


def model_symmetries(model: StateSpaceModel) -> ModelSymmetries:
    """The model's discrete symmetries and ridges (memoised per model class; deterministic:
    every random point comes from :data:`SEARCH_SEED`)."""
    key = type(model)
    if key not in _MEMO:
        syms = model_symbols(model)
        rng = np.random.default_rng(SEARCH_SEED)
        discrete, unconfirmed = discrete_symmetries(model, syms, rng)
        order = {"sign": 0, "permutation": 1, "translation": 2, "reflection": 3}
        discrete.sort(key=lambda s: (order[s.kind], len(s.name), s.name))
        _MEMO[key] = ModelSymmetries(
            discrete=tuple(discrete),
            ridges=tuple(ridges(model, syms, rng)),
            unconfirmed=tuple(unconfirmed),
        )
    return _MEMO[key]
