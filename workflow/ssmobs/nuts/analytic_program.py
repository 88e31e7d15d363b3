"""The Stan side of the analytic gradients (:mod:`ssmobs.nuts.analytic_gradients` writes the
C++): the model's Stan program with its ``model`` block replaced by one call of the generated
function, or a whole program for a model without a hand-written one, and both files written
into a content-keyed folder of the cache.

The call passes each parameter's bounds where the sampler may take the gradient without
Stan's tape (:func:`slot_bounds`; ``stan_backends/native_include/ssmobs/gradient_slot.hpp``).
"""

from __future__ import annotations

import hashlib
import os
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import sympy as sp

from ..models.base import StateSpaceModel
from .analytic_gradients import GENERATOR_VERSION, function_name, header_code, switch_name


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
    """The Stan program ``code`` (with its includes expanded) holding both model blocks: the
    call of the generated function, which NUTS runs, and ``code``'s own statements, which
    only the model check runs (the native driver's ``--autodiff-twin``) to compare the two
    from one compile; the switch and the function are declared in ``functions``."""
    bare = _blank_comments(code)
    span = _block_span(bare, "model")
    if span is None:
        raise ValueError(f"the Stan program of model '{model.slug}' has no model block")
    start, opened, close = span
    block = (
        "model {\n"
        f"  if ({switch_name(model)}()) {{\n"
        f"    // the log posterior and its gradient from the terms of models/{model.slug}.py\n"
        f"    {stan_call(model, slot_bounds(model, code))}\n"
        "  } else {  // the hand-written statements under Stan's autodiff (the model check)"
        f"{code[opened:close]}"
        "  }\n"
        "}"
    )
    code = code[:start] + block + code[close + 1 :]
    decl = (
        f"  {function_declaration(model)}  // generated C++\n"
        f"  int {switch_name(model)}();  // generated C++: 1 but in the model check's twin\n"
    )
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


def _program_texts(
    model: StateSpaceModel,
    stan_file: str | os.PathLike | None,
    root: str | os.PathLike | None,
) -> tuple[AnalyticProgram, str, str]:
    """The analytic program's files (content-keyed folder) and their texts."""
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
    return program, code, header


def analytic_program_files(
    model: StateSpaceModel,
    stan_file: str | os.PathLike | None,
    root: str | os.PathLike | None = None,
) -> AnalyticProgram:
    """Where :func:`write_analytic_program` writes the program of ``model``; writes nothing
    (a file that is not there yet has not been generated)."""
    return _program_texts(model, stan_file, root)[0]


def write_analytic_program(
    model: StateSpaceModel,
    stan_file: str | os.PathLike | None,
    root: str | os.PathLike | None = None,
) -> AnalyticProgram:
    """Generate the analytic program of ``model`` from its Stan program ``stan_file`` (None:
    a whole program, :func:`generated_stan_code`) into ``<root>/<slug>-<digest>/`` (default
    root: the cache's ``analytic/``), written once and atomically; the same inputs give the
    same directory and bytes."""
    program, code, header = _program_texts(model, stan_file, root)
    for path, text in ((program.stan_file, code), (program.header, header)):
        if path.is_file() and path.read_text() == text:
            continue
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
        tmp.write_text(text)
        os.replace(tmp, path)
    return program
