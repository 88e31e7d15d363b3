"""Analytic gradients for NUTS: C++ generated from the model's own terms, called from Stan.

The log posterior (2) of a model is -1/2 times the sum of its per-step terms,

    log pi(Theta | z) = -1/2 [ sum_t obs_term(Omega, x_t; z_t)
                               + sum_t trans_term(Omega, x_{t-1}, x_t) ] + const,

the same SymPy terms the Python side differentiates (:mod:`ssmobs.models.log_posterior`).
:func:`header_code` turns them into one C++ function that computes this value and its
gradient in Theta = (Omega, x_0, ..., x_T) in plain double loops (fixed summation order:
t = 1..T, observation term before transition term) and hands both to Stan as one node of
its autodiff tape (``stan::math::make_callback_var``), or, called with doubles by the native
sampler, writes the gradient on the unconstrained scale without a tape.
:mod:`ssmobs.nuts.analytic_program` writes the Stan program that calls it (the model's own,
its ``model`` block replaced; ``stanc --allow-undefined``, the header included before the
generated model).

For every shipped model -1/2 times the terms equals what Stan's ``~ normal`` keeps with
constants dropped, so ``lp__`` keeps its meaning.  The generated text depends on the terms
and the SymPy version only (byte-stable: the same model gives the same header).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import sympy as sp
from sympy.printing.cxx import CXX17CodePrinter

from ..models.base import StateSpaceModel

#: values of the config key ``stan.gradients``: Stan's own autodiff of the hand-written
#: program, or the generated C++ of this module
GRADIENT_MODES: tuple[str, ...] = ("autodiff", "analytic")
#: format of the generated files; change it whenever the generated text changes meaning
GENERATOR_VERSION = 5


def function_name(model: StateSpaceModel) -> str:
    """The external Stan function of a model's analytic log density."""
    return f"ssmobs_{model.slug}_log_density"


def switch_name(model: StateSpaceModel) -> str:
    """The external Stan function that picks a model block in a program holding both
    (:func:`ssmobs.nuts.analytic_program.analytic_stan_code`): 1 the generated function, 0
    the hand-written statements under Stan's autodiff (the model check's twin only)."""
    return f"ssmobs_{model.slug}_use_generated"


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
        "//! 1: the model block calls the function above; 0 only in the native driver's",
        "//! --log-density --autodiff-twin mode (the program's own statements under Stan's",
        "//! autodiff, what the model check compares with).",
        f"inline int {switch_name(model)}(std::ostream* pstream__) {{",
        "#ifdef SSMOBS_GRADIENT_SLOT_HPP",
        "  return ssmobs::autodiff_twin() ? 0 : 1;",
        "#else",
        "  return 1;",
        "#endif",
        "}",
        "",
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
