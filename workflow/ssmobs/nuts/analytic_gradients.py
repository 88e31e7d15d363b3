"""Analytic gradients for NUTS: C++ generated from the model's own terms, called from Stan.

The log posterior (2) of a model is -1/2 times the sum of its per-step terms,

    log pi(Theta | z) = -1/2 [ sum_t obs_term(Omega, x_t; z_t)
                               + sum_t trans_term(Omega, x_{t-1}, x_t) ] + const,

the same SymPy terms the Python side differentiates (:mod:`ssmobs.models.log_posterior`).
:func:`header_code` turns them into one C++ function that computes this value and its
gradient in Theta = (Omega, x_0, ..., x_T) in plain double loops (fixed summation order:
t = 1..T, observation term before transition term) and hands both to Stan as one node of
its autodiff tape (``stan::math::make_callback_var``).  :func:`analytic_stan_code` keeps the
model's Stan program (data, bounds, constraint transforms and their Jacobians stay Stan's)
and replaces its ``model`` block by one call of that function, declared without a body
(``stanc --allow-undefined``; the header is included before the generated model).

For every shipped model -1/2 times the terms equals what Stan's ``~ normal`` keeps with
constants dropped, so ``lp__`` keeps its meaning.  The generated text depends on the terms
and the SymPy version only (byte-stable: the same model gives the same header).
"""

from __future__ import annotations

import hashlib
import os
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import sympy as sp
from sympy.printing.cxx import CXX17CodePrinter

from ..models.base import StateSpaceModel

#: values of the config key ``stan.gradients``: Stan's own autodiff of the hand-written
#: program, or the generated C++ of this module
GRADIENT_MODES: tuple[str, ...] = ("autodiff", "analytic")
#: format of the generated files; change it whenever the generated text changes meaning
GENERATOR_VERSION = 4


def function_name(model: StateSpaceModel) -> str:
    """The external Stan function of a model's analytic log density."""
    return f"ssmobs_{model.slug}_log_density"


# --------------------------------------------------------------------------- C++ printing
class _Printer(CXX17CodePrinter):
    """C++ with small integer powers as products (exact, and no ``std::pow`` call)."""

    def _print_Pow(self, expr: sp.Pow) -> str:  # noqa: N802 - SymPy's naming
        base, exp = expr.base, expr.exp
        if exp.is_Integer and 1 <= abs(int(exp)) <= 4:
            b = self.parenthesize(base, sp.printing.precedence.PRECEDENCE["Mul"] + 1)
            prod = "*".join([b] * abs(int(exp)))
            if abs(int(exp)) > 1:  # one operand wherever it stands (e.g. after a division)
                prod = f"({prod})"
            return prod if int(exp) > 0 else f"(1.0/{prod})"
        if exp == sp.Rational(1, 2):
            return f"std::sqrt({self._print(base)})"
        if exp == -sp.Rational(1, 2):
            return f"(1.0/std::sqrt({self._print(base)}))"
        return f"std::pow({self._print(base)}, {self._print(exp)})"

    def _print_Rational(self, expr: sp.Rational) -> str:  # noqa: N802
        return f"({int(expr.p)}.0/{int(expr.q)}.0)"

    def _print_Integer(self, expr: sp.Integer) -> str:  # noqa: N802
        return f"{int(expr)}.0"


def _cxx(expr: sp.Expr) -> str:
    return _Printer().doprint(expr)


@dataclass(frozen=True)
class _Step:
    """One per-step term as straight-line code: Omega-only values hoisted out of the loop,
    the step's own temporaries, the value and the gradient in its local variables."""

    hoisted: list[tuple[sp.Symbol, sp.Expr]]
    body: list[tuple[sp.Symbol, sp.Expr]]
    value: sp.Expr
    grads: list[sp.Expr]


def _step(expr: sp.Expr, local: Sequence[sp.Symbol], omega: Sequence[sp.Symbol], tag: str) -> _Step:
    """Common subexpressions of the term and its gradient in ``local``; every subexpression
    that depends on Omega only is moved before the loop over t."""
    grads = [sp.diff(expr, v) for v in local]
    temps = sp.numbered_symbols(f"{tag}_c")
    replacements, reduced = sp.cse([expr, *grads], symbols=temps, order="canonical")
    invariant = set(omega)
    hoist_names = sp.numbered_symbols(f"{tag}_h")
    hoisted: list[tuple[sp.Symbol, sp.Expr]] = []
    seen: dict[sp.Expr, sp.Symbol] = {}

    def lift(e: sp.Expr) -> sp.Expr:
        """``e`` with its maximal Omega-only, non-trivial subtrees named and hoisted."""
        if e.is_Atom:
            return e
        if e.free_symbols <= invariant:
            if e not in seen:
                seen[e] = next(hoist_names)
                hoisted.append((seen[e], e))
                invariant.add(seen[e])
            return seen[e]
        return e.func(*[lift(a) for a in e.args])

    body: list[tuple[sp.Symbol, sp.Expr]] = []
    for sym, rhs in replacements:
        if rhs.free_symbols <= invariant:
            hoisted.append((sym, rhs))
            invariant.add(sym)
        else:
            body.append((sym, lift(rhs)))
    out = [lift(e) for e in reduced]
    return _Step(hoisted=hoisted, body=body, value=out[0], grads=out[1:])


def _symbols(model: StateSpaceModel) -> tuple[list[sp.Symbol], ...]:
    """The symbols of :func:`ssmobs.models.log_posterior.compile_model`."""
    m, p, d = model.n_params, model.state_dim, model.obs_dim
    w = list(sp.symbols(f"w0:{m}", real=True))
    xp = list(sp.symbols(f"xp0:{p}", real=True))
    x = list(sp.symbols(f"x0:{p}", real=True))
    z = list(sp.symbols(f"z0:{d}", real=True))
    return w, xp, x, z


def _emit_step(step: _Step, targets: list[str], indent: str) -> list[str]:
    lines = [f"{indent}const double {s} = {_cxx(e)};" for s, e in step.body]
    lines.append(f"{indent}acc += {_cxx(step.value)};")
    for target, g in zip(targets, step.grads):
        if g != 0:
            lines.append(f"{indent}{target} += {_cxx(g)};")
    return lines


def header_code(model: StateSpaceModel) -> str:
    """The C++ header of the model's analytic log density and gradient (see the module
    docstring): deterministic text for the same model terms."""
    m, p, d = model.n_params, model.state_dim, model.obs_dim
    w, xp, x, z = _symbols(model)
    obs = _step(model.obs_term(w, x, z), w + x, w, "o")
    trans = _step(model.trans_term(w, xp, x), w + xp + x, w, "r")
    guard = f"SSMOBS_ANALYTIC_{model.slug.upper()}_HPP"
    # running sums in locals (registers), not through g_w/g_x in memory: the same additions
    # in the same order, without a store and reload per term
    g_w = [f"gw{i}" for i in range(m)]
    now = [f"gx_now{i}" for i in range(p)]
    before = [f"gx_before{i}" for i in range(p)]
    out = [
        f"// Generated by ssmobs.nuts.analytic_gradients "
        f"(format {GENERATOR_VERSION}) from the terms",
        f"// of model '{model.slug}' (workflow/ssmobs/models/{model.slug}.py); do not edit.",
        "// log pi(Theta | z) = -1/2 [sum_t obs_term(Omega, x_t; z_t)",
        "//                          + sum_t trans_term(Omega, x_{t-1}, x_t)]  (Eq. (2))",
        f"#ifndef {guard}",
        f"#define {guard}",
        "#include <stan/model/model_header.hpp>",
        "#if __has_include(<ssmobs/gradient_slot.hpp>)  // the native backend's headers",
        "#include <ssmobs/gradient_slot.hpp>",
        "#endif",
        "",
        f"namespace ssmobs_analytic_{model.slug} {{",
        "",
        f"//! log density and its gradient: z (T*{d}), w ({m}), x ((T+1)*{p}), time-major",
        "inline double value_gradient(const double* z, const double* w, const double* x_all,",
        "                             const int T, double* g_w, double* g_x) {",
    ]
    out += [f"  const double {s} = w[{i}];" for i, s in enumerate(w)]
    out += [f"  const double {s} = {_cxx(e)};" for s, e in obs.hoisted + trans.hoisted]
    out += [
        "  double acc = 0.0;",
        *[f"  double {g} = 0.0;  // d/d Omega_{i}" for i, g in enumerate(g_w)],
        *[f"  double {g} = 0.0;  // d/d x_t, component {i}" for i, g in enumerate(before)],
        "  for (int t = 0; t < T; ++t) {",
        *[f"    double {g} = 0.0;  // d/d x_(t+1), component {i}" for i, g in enumerate(now)],
        "    {  // observation term at step t + 1",
    ]
    out += [f"      const double {s} = x_all[(t + 1) * {p} + {i}];" for i, s in enumerate(x)]
    out += [f"      const double {s} = z[t * {d} + {i}];" for i, s in enumerate(z)]
    out += _emit_step(obs, g_w + now, "      ")
    out += ["    }", "    {  // transition term from step t to t + 1"]
    out += [f"      const double {s} = x_all[t * {p} + {i}];" for i, s in enumerate(xp)]
    out += [f"      const double {s} = x_all[(t + 1) * {p} + {i}];" for i, s in enumerate(x)]
    out += _emit_step(trans, g_w + before + now, "      ")
    out += ["    }", "    // x_t has all its terms"]
    out += [f"    g_x[t * {p} + {i}] = {g} * -0.5;" for i, g in enumerate(before)]
    out += [f"    {b} = {n};" for b, n in zip(before, now)]
    out += ["  }"]
    out += [f"  g_x[T * {p} + {i}] = {g} * -0.5;" for i, g in enumerate(before)]
    out += [f"  g_w[{i}] = {g} * -0.5;" for i, g in enumerate(g_w)]
    out += [
        "  return -0.5 * acc;",
        "}",
        "",
        "#ifdef SSMOBS_GRADIENT_SLOT_HPP",
        "//! the sampler may ask this program's log density for its gradient without the tape",
        "static const bool writes_slots = (ssmobs::program_writes_slots() = true);",
        "#endif",
        "",
        f"}}  // namespace ssmobs_analytic_{model.slug}",
        "",
    ]
    out += _stan_function(model)
    out += [
        f"#endif  // {guard}",
        "",
    ]
    return "\n".join(out)


def _stan_function(model: StateSpaceModel) -> list[str]:
    """The Stan function's C++: the values of z, Omega, x_0 and x copied time-major into one
    buffer per thread, :func:`header_code`'s ``value_gradient`` on them, and one callback
    node on the tape that adds adj * gradient to every operand (no heap allocation)."""
    m, p, d = model.n_params, model.state_dim, model.obs_dim
    name, ns = function_name(model), f"ssmobs_analytic_{model.slug}"
    var_vec = "Eigen::Matrix<stan::math::var, Eigen::Dynamic, 1>"
    var_mat = "Eigen::Matrix<stan::math::var, Eigen::Dynamic, Eigen::Dynamic>"
    x_arena = var_vec if p == 1 else var_mat
    omega = [f"omega{i}" for i in range(m)]
    types = ", ".join([f"T_w{i}" for i in range(m)] + ["T_x0", "T_x"])
    args = "".join(f"const T_w{i}& {w}, " for i, w in enumerate(omega))
    bound_args = "".join(f"const double {w}_lower, const double {w}_upper, " for w in omega)
    pad = " " * (len(name) + 1)
    out = [
        "//! The Stan function: z (data; a matrix when d > 1), each parameter of Omega, x_0 (a",
        "//! real when p = 1) and x_1..x_T (a matrix T x p when p > 1) as the program declares",
        "//! them, then each parameter's bounds (NaN: not given); one callback node on the tape",
        "//! adds adj * gradient to every operand.  With doubles and an armed slot (the native",
        "//! sampler, ssmobs/gradient_slot.hpp), the gradient on the unconstrained scale goes",
        "//! to the slot instead: Omega's through its bound transform, then x_0, then x",
        "//! column-major, as the program's parameters block orders them.",
        f"template <typename T_z, {', '.join('typename ' + t for t in types.split(', '))}>",
        f"stan::return_type_t<{types}>",
        f"{name}(const T_z& z, {args}const T_x0& x0, const T_x& x,",
        f"{pad}{bound_args}std::ostream* pstream__) {{",
        f'  static constexpr const char* fn = "{name}";',
        "  const int T = static_cast<int>(z.rows());",
    ]
    if d > 1:
        out.append(f'  stan::math::check_size_match(fn, "columns of z", z.cols(), "d", {d});')
    if p > 1:
        out.append(f'  stan::math::check_size_match(fn, "size of x0", x0.size(), "p", {p});')
        out.append(f'  stan::math::check_size_match(fn, "columns of x", x.cols(), "p", {p});')
    out += [
        '  stan::math::check_size_match(fn, "rows of x", x.rows(), "T", T);',
        "  thread_local std::vector<double> values;  // no allocation per call",
        f"  values.resize({m} + (T + 1) * {p} + T * {d});",
        "  double* const w_v = values.data();",
        f"  double* const x_v = w_v + {m};",
        f"  double* const z_v = x_v + (T + 1) * {p};",
    ]
    out += [f"  w_v[{i}] = stan::math::value_of({w});" for i, w in enumerate(omega)]
    if p == 1:
        out.append("  x_v[0] = stan::math::value_of(x0);")
    else:
        out.append(f"  for (int i = 0; i < {p}; ++i) x_v[i] = stan::math::value_of(x0.coeff(i));")
    out += [
        "  for (int t = 0; t < T; ++t)",
        f"    for (int i = 0; i < {p}; ++i)",
        f"      x_v[(t + 1) * {p} + i] = stan::math::value_of(x.coeff(t, i));",
        "  for (int t = 0; t < T; ++t)",
        f"    for (int i = 0; i < {d}; ++i) z_v[t * {d} + i] = z.coeff(t, i);",
        f"  const int n_grad = {m} + (T + 1) * {p};",
        f"  if constexpr (stan::is_constant_all<{types}>::value) {{",
        "    thread_local std::vector<double> grad;",
        "    grad.resize(n_grad);",
        f"    const double lp = {ns}::value_gradient(z_v, w_v, x_v, T, grad.data(), "
        f"grad.data() + {m});",
        "#ifdef SSMOBS_GRADIENT_SLOT_HPP",
        "    ssmobs::gradient_slot* const slot = ssmobs::armed_slot();",
        "    const bool bounds_given = "
        + " && ".join(f"!std::isnan({w}_lower) && !std::isnan({w}_upper)" for w in omega)
        + ";",
        "    if (slot != nullptr && bounds_given && slot->size == n_grad) {",
        "      double* const out = slot->grad;",
        "      const double* const u = slot->theta;",
        *[
            f"      out[{i}] = ssmobs::bound_chain(grad[{i}], u[{i}], {w}_lower, {w}_upper);"
            for i, w in enumerate(omega)
        ],
        f"      for (int i = 0; i < {p}; ++i) out[{m} + i] = ssmobs::free_chain(grad[{m} + i]);",
        f"      for (int i = 0; i < {p}; ++i)",
        "        for (int t = 0; t < T; ++t)",
        f"          out[{m + p} + i * T + t] = ssmobs::free_chain(grad[{m} + (t + 1) * {p} + i]);",
        "      ++slot->writes;",
        "    }",
        "#endif",
        "    return lp;",
        "  } else {",
        "    double* const g =",
        "        stan::math::ChainableStack::instance_->memalloc_.alloc_array<double>(n_grad);",
        f"    const double lp = {ns}::value_gradient(z_v, w_v, x_v, T, g, g + {m});",
    ]
    out += [f"    stan::math::var {w}_var = {w};" for w in omega]
    captures = ", ".join([f"{w}_var" for w in omega] + ["x0_var", "x_arena", "g", "T"])
    if p == 1:
        out.append("    stan::math::var x0_var = x0;")
    else:
        out.append(f"    stan::arena_t<{var_vec}> x0_var = x0;")
    out += [
        f"    stan::arena_t<{x_arena}> x_arena = x;",
        "    return stan::math::make_callback_var(",
        f"        lp, [{captures}](auto& vi) mutable {{",
        "          const double a = vi.adj();",
    ]
    out += [f"          {w}_var.adj() += a * g[{i}];" for i, w in enumerate(omega)]
    if p == 1:
        out.append(f"          x0_var.adj() += a * g[{m}];")
    else:
        out.append(
            f"          for (int i = 0; i < {p}; ++i) x0_var.coeffRef(i).adj() += a * g[{m} + i];"
        )
    out += [
        "          for (int t = 0; t < T; ++t)",
        f"            for (int i = 0; i < {p}; ++i)",
        f"              x_arena.coeffRef(t, i).adj() += a * g[{m} + (t + 1) * {p} + i];",
        "        });",
        "  }",
        "}",
        "",
    ]
    return out


# --------------------------------------------------------------------------- Stan program
def _blank_comments(code: str) -> str:
    """``code`` with comments replaced by spaces (newlines kept): positions stay valid."""

    def blank(match: re.Match[str]) -> str:
        return re.sub(r"[^\n]", " ", match.group(0))

    return re.sub(r"/\*.*?\*/|//[^\n]*|#[^\n]*", blank, code, flags=re.S)


def _block_span(bare: str, name: str) -> tuple[int, int, int] | None:
    """(start of the keyword, position after ``{``, position of the closing ``}``) of the
    top-level block ``name`` (not ``transformed``/``generated`` ``name``)."""
    for match in re.finditer(rf"\b{name}\s*\{{", bare):
        if bare[: match.start()].rstrip().endswith(("transformed", "generated")):
            continue
        depth = 1
        for i in range(match.end(), len(bare)):
            depth += {"{": 1, "}": -1}.get(bare[i], 0)
            if depth == 0:
                return match.start(), match.end(), i
    return None


#: a bound the program does not give the generated function: its gradient then goes
#: through Stan's tape (the bound may depend on another parameter)
NO_BOUND = "not_a_number()"


def stan_call(model: StateSpaceModel, bounds: Sequence[tuple[str, str]] | None = None) -> str:
    """The model block's statement: the program's z, parameters, x0 and x as it declares
    them (``z`` a ``matrix[T, d]`` when d > 1, ``x0`` a ``vector[p]`` and ``x`` a
    ``matrix[T, p]`` when p > 1; no argument is a new vector), then each parameter's
    (lower, upper) bound expressions (:func:`slot_bounds`; None: :data:`NO_BOUND`)."""
    pairs = bounds if bounds is not None else [(NO_BOUND, NO_BOUND)] * model.n_params
    args = ", ".join(["z", *model.param_names, "x0", "x", *(e for pair in pairs for e in pair)])
    return f"target += {function_name(model)}({args});"


def function_declaration(model: StateSpaceModel) -> str:
    """The Stan declaration (no body) of the generated function of :func:`header_code`."""
    z = "data vector z" if model.obs_dim == 1 else "data matrix z"
    omega = ", ".join(f"real omega{i}" for i in range(model.n_params))
    states = "real x0, vector x" if model.state_dim == 1 else "vector x0, matrix x"
    bounds = ", ".join(
        f"data real omega{i}_lower, data real omega{i}_upper" for i in range(model.n_params)
    )
    return f"real {function_name(model)}({z}, {omega}, {states}, {bounds});"


def _split_top(text: str, sep: str) -> list[str]:
    """``text`` split at ``sep`` outside parentheses and brackets."""
    parts, depth, start = [], 0, 0
    for i, ch in enumerate(text):
        depth += {"(": 1, "[": 1, ")": -1, "]": -1}.get(ch, 0)
        if ch == sep and depth == 0:
            parts.append(text[start:i])
            start = i + 1
    parts.append(text[start:])
    return parts


_DECLARATION = re.compile(r"^(real|vector|matrix)\s*(?:<(.*)>)?\s*(\[[^\]]*\])?\s*(\w+)$", re.S)


def slot_bounds(model: StateSpaceModel, code: str) -> list[tuple[str, str]] | None:
    """(lower, upper) Stan expressions of each parameter of Omega when the program's
    parameters block is Omega (reals, in the model's order, bounded by data alone), then
    x0, then x, and it has no transformed parameters: then the sampler can take the
    gradient from the generated function (``ssmobs/gradient_slot.hpp``).  None otherwise,
    e.g. a bound that depends on another parameter (``stan/sep_d1_p2.stan``)."""
    bare = _blank_comments(code)
    if re.search(r"\btransformed\s+parameters\s*\{", bare):
        return None
    span = _block_span(bare, "parameters")
    if span is None:
        return None
    statements = [t.strip() for t in bare[span[1] : span[2]].split(";")]
    if statements and statements[-1] == "":
        statements.pop()
    found = [_DECLARATION.match(t) for t in statements]
    if any(f is None for f in found):
        return None
    decls = [(f.group(1), f.group(2), f.group(3), f.group(4)) for f in found if f is not None]
    m, p = model.n_params, model.state_dim
    names = [d[3] for d in decls]
    if names != [*model.param_names, "x0", "x"]:
        return None
    x0_kind, x_kind = ("real", "vector") if p == 1 else ("vector", "matrix")
    if (decls[m][0], decls[m + 1][0]) != (x0_kind, x_kind) or decls[m][1] or decls[m + 1][1]:
        return None
    out = []
    for kind, constraint, dims, _ in decls[:m]:
        if kind != "real" or dims:
            return None
        found_bounds = {"lower": "negative_infinity()", "upper": "positive_infinity()"}
        for part in _split_top(constraint or "", ",") if constraint else []:
            key, eq, expr = part.partition("=")
            if not eq or key.strip() not in found_bounds:
                return None  # offset, multiplier
            if any(re.search(rf"\b{n}\b", expr) for n in names):
                return None  # a bound that depends on a parameter
            found_bounds[key.strip()] = " ".join(expr.split())
        out.append((found_bounds["lower"], found_bounds["upper"]))
    return out


def analytic_stan_code(model: StateSpaceModel, code: str) -> str:
    """The Stan program ``code`` (with its includes expanded) with its ``model`` block
    replaced by the call of the generated function, declared in ``functions``."""
    bare = _blank_comments(code)
    span = _block_span(bare, "model")
    if span is None:
        raise ValueError(f"the Stan program of model '{model.slug}' has no model block")
    start, _, close = span
    block = (
        "model {\n"
        f"  // the log posterior and its gradient from the terms of models/{model.slug}.py\n"
        f"  {stan_call(model, slot_bounds(model, code))}\n"
        "}"
    )
    code = code[:start] + block + code[close + 1 :]
    decl = f"  {function_declaration(model)}  // generated C++\n"
    bare = _blank_comments(code)
    functions = _block_span(bare, "functions")
    if functions is not None:
        at = functions[1]
        return code[:at] + "\n" + decl + code[at:]
    first = re.search(r"\b(data|transformed\s+data|parameters)\s*\{", bare)
    at = first.start() if first else 0
    return code[:at] + "functions {\n" + decl + "}\n" + code[at:]


def generation_problem(model: StateSpaceModel, backend: str | None = None) -> str | None:
    """One line when :func:`generated_stan_code` cannot write the model's program (support
    constraints c(Omega) > 0, which Stan's parameter bounds do not express) or the Stan
    ``backend`` cannot run it (PyStan takes no external C++), else None."""
    w = sp.symbols(f"w0:{model.n_params}", real=True)
    if not model.support_constraints(list(w)):
        if backend != "pystan":
            return None
        return (
            f"model {model.slug!r} has no Stan program stan/{model.slug}.stan, and the "
            f"generated one needs external C++, which the pystan backend does not take: "
            f"choose stan.backend 'native', 'cmdstanpy' or 'auto', or write "
            f"stan/{model.slug}.stan (docs/your-own-model.md)"
        )
    return (
        f"model '{model.slug}' has support constraints "
        f"({', '.join(model.constraint_text) or 'support_constraints'}), which a generated "
        f"Stan program cannot express with parameter bounds: write stan/{model.slug}.stan "
        f"by hand (docs/your-own-model.md)"
    )


def generated_bounds(
    model: StateSpaceModel, lower: Sequence[float], upper: Sequence[float]
) -> list[tuple[float, float]]:
    """(lo, hi) of each parameter in the program of :func:`generated_stan_code` (its
    ``transformed data``) for prior bounds ``lower``/``upper``: the interval cut to (-1, 1)
    or (0, inf) by the parameter's kind."""
    out = []
    for name, lo, hi in zip(model.param_names, lower, upper):
        lo, hi = float(lo), float(hi)
        if name in model.unit_interval_params:
            lo, hi = max(lo, -1.0), min(hi, 1.0)
        elif name in model.positive_params:
            lo = max(lo, 0.0)
        out.append((lo, hi))
    return out


def generated_stan_code(model: StateSpaceModel) -> str:
    """A whole Stan program for a model without a hand-written one: data ``T``, ``z`` and
    the prior bounds ``<name>_lower``/``<name>_upper``; each parameter bounded by its prior
    interval cut to (-1, 1) (:attr:`~ssmobs.models.base.StateSpaceModel.unit_interval_params`)
    or to (0, inf) (``positive_params``); ``x0``, ``x``; the model block of
    :func:`analytic_stan_code`.  ValueError for a model with ``support_constraints``, which
    bounds alone do not express (its program is written by hand, as ``stan/sep_d1_p2.stan``)."""
    problem = generation_problem(model)
    if problem is not None:
        raise ValueError(problem)
    T_vec = "vector[T]" if model.obs_dim == 1 else f"matrix[T, {model.obs_dim}]"
    lines = [
        f"// Generated by ssmobs.nuts.analytic_gradients (format {GENERATOR_VERSION}) from",
        f"// workflow/ssmobs/models/{model.slug}.py: its log posterior (2) with flat priors",
        "// on Omega over their intervals and a flat prior on x0.",
        "functions {",
        f"  {function_declaration(model)}",
        "}",
        "data {",
        "  int<lower=1> T;  // number of time steps",
        f"  {T_vec} z;  // observations z_1..z_T",
    ]
    for name in model.param_names:
        lines += [
            f"  real {name}_lower;  // bounds of the flat prior on {name} (may be infinite)",
            f"  real<lower={name}_lower> {name}_upper;",
        ]
    lines += ["}", "transformed data {"]
    for name in model.param_names:
        lo, hi = f"{name}_lower", f"{name}_upper"
        if name in model.unit_interval_params:
            lo, hi = f"fmax({lo}, -1)", f"fmin({hi}, 1)"
        elif name in model.positive_params:
            lo = f"fmax({lo}, 0)"
        lines += [
            f"  real {name}_lo = {lo};",
            f"  real {name}_hi = {hi};",
            f"  if (!({name}_lo < {name}_hi)) {{",
            f'    reject("empty support for {name}: (", {name}_lo, ", ", {name}_hi, ")");',
            "  }",
        ]
    x0 = "real" if model.state_dim == 1 else f"vector[{model.state_dim}]"
    x = "vector[T]" if model.state_dim == 1 else f"matrix[T, {model.state_dim}]"
    lines += ["}", "parameters {"]
    lines += [f"  real<lower={n}_lo, upper={n}_hi> {n};" for n in model.param_names]
    lines += [f"  {x0} x0;  // initial state x_0", f"  {x} x;  // states x_1..x_T", "}"]
    bounds = [(f"{n}_lo", f"{n}_hi") for n in model.param_names]
    lines += ["model {", f"  {stan_call(model, bounds)}", "}", ""]
    return "\n".join(lines)


# --------------------------------------------------------------------------- files
@dataclass(frozen=True)
class AnalyticProgram:
    """A generated Stan program and its header, in a content-keyed directory."""

    stan_file: Path
    header: Path

    @property
    def digest(self) -> str:
        """SHA-256 (16 hex digits) of both texts: what the program's records are keyed by."""
        text = self.stan_file.read_text() + "\n//--\n" + self.header.read_text()
        return hashlib.sha256(text.encode()).hexdigest()[:16]


def write_analytic_program(
    model: StateSpaceModel,
    stan_file: str | os.PathLike | None,
    root: str | os.PathLike | None = None,
) -> AnalyticProgram:
    """Generate the analytic program of ``model`` from its Stan program ``stan_file`` (None:
    a whole program, :func:`generated_stan_code`) into ``<root>/<slug>-<digest>/`` (default
    root: the cache's ``analytic/``), written once and atomically; the same inputs give the
    same directory and bytes."""
    from ..stan_backends.base import program_code
    from ..stan_backends.cache import cache_root

    code = (
        generated_stan_code(model)
        if stan_file is None
        else analytic_stan_code(model, program_code(stan_file))
    )
    header = header_code(model)
    key = hashlib.sha256((code + "\n//--\n" + header).encode()).hexdigest()[:16]
    base = Path(root) if root is not None else cache_root() / "analytic"
    folder = base / f"{model.slug}-{key}"
    program = AnalyticProgram(
        stan_file=folder / f"{model.slug}_analytic.stan",
        header=folder / f"{model.slug}_analytic.hpp",
    )
    for path, text in ((program.stan_file, code), (program.header, header)):
        if path.is_file() and path.read_text() == text:
            continue
        folder.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
        tmp.write_text(text)
        os.replace(tmp, path)
    return program
