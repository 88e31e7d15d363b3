"""The generated analytic gradients (issue 49) without compiling: byte-stable text, a Stan
program that keeps everything of the hand-written one and adds the generated model block
beside its own (one compile for NUTS and the model check's twin), and a header
whose value and gradient, read back as arithmetic, are the Python model's."""

from __future__ import annotations

import os
import re
import subprocess
import sys

import numpy as np
import pytest
from ssmobs.model_check.stan_source import stan_block
from ssmobs.models import MODELS, get_model
from ssmobs.models.check_cases import default_cases
from ssmobs.models.log_posterior import neg2_log_posterior
from ssmobs.nuts.analytic_gradients import header_code, switch_name
from ssmobs.nuts.analytic_program import (
    analytic_stan_code,
    function_declaration,
    slot_bounds,
    stan_call,
)
from ssmobs.stan_backends import stan_file
from ssmobs.stan_backends.base import program_code

pytestmark = pytest.mark.unit


def _header_in_fresh_process(slug: str, hashseed: str) -> str:
    code = (
        "from ssmobs.nuts.analytic_gradients import header_code as h\n"
        "from ssmobs.models import get_model as g\n"
        f"print(h(g({slug!r})), end='')"
    )
    env = {**os.environ, "PYTHONHASHSEED": hashseed}
    return subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True
    ).stdout


@pytest.mark.parametrize("slug", ["same", "sep_d1_p2"])
def test_generation_is_byte_stable(slug):
    here = header_code(get_model(slug))
    assert _header_in_fresh_process(slug, "1") == here
    assert _header_in_fresh_process(slug, "4242") == here


@pytest.mark.parametrize("slug", sorted(MODELS))
def test_program_keeps_everything_and_adds_the_generated_model_block(slug):
    model = get_model(slug)
    code = program_code(stan_file(model.slug))
    new = analytic_stan_code(model, code)
    for block in ("data", "parameters"):
        assert stan_block(new, block) == stan_block(code, block)
    # the switch picks the generated call; the hand-written statements follow unchanged
    model_block = stan_block(new, "model")
    head, _, rest = model_block.partition("} else {")
    assert head.strip().startswith(f"if ({switch_name(model)}()) {{")
    assert head.strip().endswith(stan_call(model, slot_bounds(model, code)))
    own = rest.split("\n", 1)[1].rstrip().removesuffix("}")
    assert own.split() == stan_block(code, "model").split()
    functions = stan_block(new, "functions").strip()
    assert functions.startswith(function_declaration(model))
    assert f"int {switch_name(model)}();" in functions
    # the states go as the program declares them, no copy joins x0 and x
    declared = "real x0" if model.state_dim == 1 else "vector x0"
    assert declared in function_declaration(model) and "append_row" not in stan_call(model)


def _evaluate_header(model, theta: np.ndarray, z: np.ndarray) -> tuple[float, np.ndarray]:
    """Run the generated loop's arithmetic in Python (C++ statements mapped one to one)."""
    text = header_code(model)
    body = text.split("const int T, double* g_w, double* g_x) {", 1)[1].split("\n}\n", 1)[0]
    m, p = model.n_params, model.state_dim
    T = z.shape[0]
    env = {
        "w": theta[:m].tolist(),
        "x_all": theta[m:].tolist(),
        "z": z.reshape(-1).tolist(),
        "T": T,
        "g_w": [0.0] * m,
        "g_x": [0.0] * (p * (T + 1)),
        "std": type("std", (), {"log": np.log, "exp": np.exp, "sqrt": np.sqrt}),
    }
    py = []
    for raw in body.splitlines():
        line = raw.split("//", 1)[0].strip()  # C++ divides with a single slash
        if not line or line.startswith(("{", "}")):
            continue
        inside = len(raw) - len(raw.lstrip()) >= 4  # the statements of the loop over t
        loop = re.fullmatch(r"for \(int (\w) = 0; \w < (.*?); \+\+\w\) (.*)", line)
        if line.startswith("for (int t"):
            line = "for t in range(T):"
        elif loop:
            line = f"for {loop.group(1)} in range({loop.group(2)}): {loop.group(3)}"
        line = re.sub(r"^(const )?double ", "", line).replace("std::", "std.").rstrip(";{ ")
        py.append(("    " if inside else "") + line.replace("return ", "result = "))
    exec("\n".join(py), env)  # noqa: S102 - our own generated text
    return env["result"], np.array(env["g_w"] + env["g_x"])


@pytest.mark.parametrize("slug", sorted(MODELS))
def test_header_arithmetic_is_the_python_model(slug):
    model = get_model(slug)
    rng = np.random.default_rng(3)
    T = 5
    bounds = model.prior_bounds(default_cases(model)[0].omega)
    lo = np.where(np.isfinite(bounds.lower), bounds.lower, 0.0)
    hi = np.where(np.isfinite(bounds.upper), bounds.upper, 2.0)
    omega = lo + (hi - lo) * rng.uniform(0.3, 0.5, size=model.n_params)
    theta = np.concatenate([omega, rng.normal(size=model.state_dim * (T + 1))])
    z = rng.normal(size=(T, model.obs_dim))
    value, grad = _evaluate_header(model, theta, z)
    v, g = neg2_log_posterior(model, theta, z, order=1)
    np.testing.assert_allclose(value, -0.5 * v, rtol=1e-13)
    np.testing.assert_allclose(grad, -0.5 * g, rtol=1e-12, atol=1e-13)


def test_whole_program_declares_what_the_model_check_reads():
    from ssmobs.model_check.stan_source import declared_names, expected_parameters
    from ssmobs.nuts.analytic_program import generated_stan_code

    model = get_model("sep_d2_p1")
    code = generated_stan_code(model)
    assert declared_names(stan_block(code, "parameters")) == expected_parameters(model)
    data = declared_names(stan_block(code, "data"))
    assert data == ["T", "z", "a_lower", "a_upper", "b_lower", "b_upper", "c_lower", "c_upper"]
    assert "matrix[T, 2] z;" in code and "real<lower=a_lo, upper=a_hi> a;" in code
    bounds = [("a_lo", "a_hi"), ("b_lo", "b_hi"), ("c_lo", "c_hi")]
    assert stan_block(code, "model").strip() == stan_call(model, bounds)
    assert slot_bounds(model, code) == bounds


#: what the shipped programs give the generated function as bounds; None: the tape
SHIPPED_SLOT_BOUNDS = {
    "same": [("a_lo", "a_hi")],
    "sep": [("a_lo", "a_hi"), ("b_lo", "b_hi")],
    "sep_d1_p2": None,  # b's bounds depend on a
    "sep_d2_p1": [("a_lo", "a_hi"), ("b_lo", "b_hi"), ("c_lo", "c_hi")],
    "sep_mult": [("a_lo", "a_upper")],
    "sep_ranwalk": [("a_lower", "a_upper")],
    "stoch_vol": [("phi_lower", "phi_upper"), ("sigma_lo", "sigma_upper")],
}


@pytest.mark.parametrize("slug", sorted(MODELS))
def test_slot_bounds_of_the_shipped_programs(slug):
    model = get_model(slug)
    code = program_code(stan_file(slug))
    assert slot_bounds(model, code) == SHIPPED_SLOT_BOUNDS[slug]
    call = stan_call(model, slot_bounds(model, code))
    assert call.count("not_a_number()") == (2 * model.n_params if slug == "sep_d1_p2" else 0)


@pytest.mark.parametrize(
    ("edit", "want"),
    [
        (lambda c: c, [("a_lo", "a_hi")]),
        (
            lambda c: c.replace("<lower=a_lo, upper=a_hi>", "<lower=a_lo>"),
            [("a_lo", "positive_infinity()")],
        ),
        (
            lambda c: c.replace("<lower=a_lo, upper=a_hi>", ""),
            [("negative_infinity()", "positive_infinity()")],
        ),
        (lambda c: c.replace("upper=a_hi>", "upper=fmin(a_hi, 0.5 + 0 * x0)>"), None),
        (lambda c: c.replace("<lower=a_lo, upper=a_hi>", "<offset=1>"), None),
        (
            lambda c: c.replace("model {", "transformed parameters {\n  real b = a;\n}\nmodel {"),
            None,
        ),
        (lambda c: c.replace("real x0;", "real x00;"), None),
        (
            lambda c: c.replace("  real x0;  // initial state x_0\n", "").replace(
                "vector[T] x;", "vector[T] x;\n  real x0;"
            ),
            None,
        ),
    ],
)
def test_slot_bounds_only_where_the_gradient_can_skip_the_tape(edit, want):
    """Bounds go to the generated function only for Omega's reals bounded by data, then
    x0 and x, and no transformed parameters: else the sampler keeps Stan's tape."""
    model = get_model("same")
    code = edit(program_code(stan_file("same")))
    assert slot_bounds(model, code) == want


def test_whole_program_refuses_support_constraints():
    from ssmobs.nuts.analytic_program import generated_stan_code

    with pytest.raises(ValueError, match="a\\^2 \\+ b\\^2 < 1|support constraints"):
        generated_stan_code(get_model("sep_d1_p2"))
