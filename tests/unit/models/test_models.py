"""The models (the six of Section IV and ours): derivatives, simulation, disturbances, priors."""

from __future__ import annotations

import numpy as np
import pytest
from ssmobs.models import MODELS, get_model
from ssmobs.models.log_posterior import (
    compile_model,
    in_support,
    log_posterior,
    neg2_log_posterior,
    neg2_log_posterior_blocks,
)

pytestmark = pytest.mark.unit

#: true values used throughout (the paper's where it gives them; Sec. IV)
TRUE = {
    "same": ([0.9], [8.0]),
    "sep": ([0.9, 0.9], [8.0]),
    "sep_d2_p1": ([0.9, 0.9, 0.9], [8.0]),
    "sep_d1_p2": ([0.6, 0.5, 0.9, 0.9], [8.0, 8.0]),
    "sep_ranwalk": ([0.9], [8.0]),
    "sep_mult": ([0.9], [8.0]),
    "stoch_vol": ([0.9, 0.5], [0.0]),  # ours (config/stoch_vol.yaml); not in the paper
}


def random_inside(model, T: int, K: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Random Theta strictly inside the support (and states away from 0) and random z."""
    rng = np.random.default_rng(seed)
    omega_true = np.array(TRUE[model.slug][0])
    bounds = model.prior_bounds(omega_true)
    lo = np.where(np.isfinite(bounds.lower), bounds.lower, -3.0)
    hi = np.where(np.isfinite(bounds.upper), bounds.upper, 3.0)
    omega = lo + (hi - lo) * rng.uniform(0.15, 0.55, size=(K, model.n_params))
    assert in_support(model, omega, bounds).all()
    states = rng.uniform(1.0, 4.0, size=(K, model.state_dim * (T + 1)))
    z = rng.normal(size=(K, T, model.obs_dim)) * 2.0
    return np.concatenate([omega, states], axis=1), z


@pytest.mark.parametrize("slug", sorted(MODELS))
def test_gradient_and_hessian_match_finite_differences(slug):
    model = get_model(slug)
    T, K = 4, 3
    theta, z = random_inside(model, T, K, seed=len(slug))
    value, grad, hess = neg2_log_posterior(model, theta, z, order=2)
    n = theta.shape[1]
    h = 1e-6
    fd_grad = np.empty((K, n))
    fd_hess = np.empty((K, n, n))
    for j in range(n):
        e = np.zeros(n)
        e[j] = h * (1.0 + np.abs(theta[:, j])).max()
        fp, gp = neg2_log_posterior(model, theta + e, z, order=1)
        fm, gm = neg2_log_posterior(model, theta - e, z, order=1)
        fd_grad[:, j] = (fp - fm) / (2 * e[j])
        fd_hess[:, :, j] = (gp - gm) / (2 * e[j])
    scale_g = 1.0 + np.abs(grad).max()
    scale_h = 1.0 + np.abs(hess).max()
    assert np.abs(grad - fd_grad).max() < 1e-6 * scale_g * 10
    assert np.abs(hess - fd_hess).max() < 1e-6 * scale_h * 10
    assert np.allclose(hess, np.swapaxes(hess, 1, 2))


@pytest.mark.parametrize("slug", sorted(MODELS))
def test_the_value_has_the_same_bits_at_every_order(slug):
    """The line search asks for the value alone (order 0: the per-step terms' statements
    pruned to the value's); the Newton step for all of it: the two values must be the same
    numbers, or a step accepted by the search would be judged on another function (and the
    joint MAP's results would move in the last bits)."""
    model = get_model(slug)
    theta, z = random_inside(model, T=6, K=5, seed=11)
    (v0,) = neg2_log_posterior(model, theta, z, order=0)
    v1, _ = neg2_log_posterior(model, theta, z, order=1)
    v2, _, _ = neg2_log_posterior(model, theta, z, order=2)
    vb, _, _ = neg2_log_posterior_blocks(model, theta, z)
    assert v0.shape == (5,)
    for other in (v1, v2, vb):
        np.testing.assert_array_equal(v0, other)
    # one trajectory: the leading axis is dropped, the number is the same
    (single,) = neg2_log_posterior(model, theta[2], z[2], order=0)
    assert np.ndim(single) == 0 and single == v0[2]


@pytest.mark.parametrize("slug", sorted(MODELS))
def test_block_hessian_equals_dense(slug):
    model = get_model(slug)
    theta, z = random_inside(model, T=5, K=4, seed=7)
    value, grad, hess = neg2_log_posterior(model, theta, z, order=2)
    v2, g2, blocks = neg2_log_posterior_blocks(model, theta, z)
    assert np.allclose(value, v2, rtol=1e-13, atol=1e-12)
    assert np.allclose(grad, g2, rtol=1e-12, atol=1e-10)
    assert np.allclose(hess, blocks.to_dense(), rtol=1e-12, atol=1e-10)
    # banded plus m dense rows/columns: nothing outside the arrow pattern
    m, p = model.n_params, model.state_dim
    n = theta.shape[1]
    idx = np.arange(n)
    far = (np.abs(idx[:, None] - idx[None, :]) >= 2 * p) & (idx[:, None] >= m) & (idx[None, :] >= m)
    assert np.all(hess[:, far] == 0)


def test_log_posterior_of_same_matches_paper_formula():
    """pi of (Same, d=p=1) as printed in Sec. II.A, Example 2 (up to a constant)."""
    model = get_model("same")
    theta, z = random_inside(model, T=6, K=2, seed=3)
    a, x = theta[:, 0], theta[:, 1:]
    zz = z[:, :, 0]
    paper = -0.5 / (1 - a**2) * (
        ((zz - a[:, None] * x[:, 1:]) ** 2).sum(1)
        + ((x[:, 1:] - a[:, None] * x[:, :-1]) ** 2).sum(1)
    ) - 6 * np.log(1 - a**2)
    ours = log_posterior(model, theta, z)
    assert np.allclose(ours - paper, 0.0, atol=1e-10)


def test_outside_support_is_infinite():
    model = get_model("sep_d1_p2")
    theta, z = random_inside(model, T=3, K=2, seed=1)
    bounds = model.prior_bounds(TRUE["sep_d1_p2"][0])
    theta[0, :2] = [0.8, 0.7]  # a^2 + b^2 > 1 although both in (0, 1)
    (v,) = neg2_log_posterior(model, theta, z, bounds)
    assert np.isinf(v[0]) and np.isfinite(v[1])


def test_constraint_derivatives_match_finite_differences():
    cons = compile_model(get_model("sep_d1_p2")).constraints
    omega = np.array([[0.3, 0.4, 0.5, 0.6], [0.1, 0.7, 0.2, 0.9]])
    c = cons.values(omega)
    dc, d2c = cons.derivatives(omega)
    assert cons.count == 1
    assert c.shape == (2, 1) and dc.shape == (2, 1, 4) and d2c.shape == (2, 1, 4, 4)
    assert np.allclose(c[:, 0], 1 - omega[:, 0] ** 2 - omega[:, 1] ** 2)
    assert cons.satisfied(omega).tolist() == [True, True]
    assert cons.values(omega[1]).shape == (1,) and np.allclose(cons.values(omega[1]), c[1])
    assert cons.satisfied(np.array([[0.8, 0.7, 0.5, 0.6]])).tolist() == [False]
    h = 1e-6
    for j in range(4):
        e = np.zeros(4)
        e[j] = h
        (dp, _), (dm, _) = cons.derivatives(omega + e), cons.derivatives(omega - e)
        assert np.allclose(
            (cons.values(omega + e) - cons.values(omega - e))[:, 0] / (2 * h),
            dc[:, 0, j],
            atol=1e-8,
        )
        assert np.allclose((dp - dm)[:, 0] / (2 * h), d2c[:, 0, :, j], atol=1e-6)
    none = compile_model(get_model("same")).constraints
    c0, (dc0, d2c0) = none.values(omega[:, :1]), none.derivatives(omega[:, :1])
    assert none.count == 0 and none.satisfied(omega[:, :1]).all()
    assert c0.shape == (2, 0) and dc0.shape == (2, 0, 1) and d2c0.shape == (2, 0, 1, 1)


@pytest.mark.parametrize("slug", sorted(MODELS))
def test_simulate_shapes_and_design_trajectories(slug):
    model = get_model(slug)
    omega, x0 = TRUE[slug]
    T, K = 6, 5
    d, p = model.obs_dim, model.state_dim
    matrix = np.random.default_rng(0).standard_normal(((d + p) * T, K))
    x, z = model.design_trajectories(omega, x0, matrix, T)
    assert x.shape == (K, T, p) and z.shape == (K, T, d)
    assert np.all(np.isfinite(x)) and np.all(np.isfinite(z))
    x_start = model.initial_states(np.array(omega), z)
    assert x_start.shape == (K, T, p)


def test_simulate_is_the_state_equation():
    """Same: x_1 = a x0 + sqrt(1 - a^2) eta_1, z_1 = a x_1 + sqrt(1 - a^2) eps_1 (Example 5)."""
    model = get_model("same")
    T, K = 3, 4
    matrix = np.random.default_rng(1).standard_normal((2 * T, K))
    x, z = model.design_trajectories([0.9], [8.0], matrix, T)
    eta, eps = matrix[:T].T, matrix[T:].T
    s = np.sqrt(1 - 0.81)
    assert np.allclose(x[:, 0, 0], 0.9 * 8 + s * eta[:, 0])
    assert np.allclose(x[:, 2, 0], 0.9 * x[:, 1, 0] + s * eta[:, 2])
    assert np.allclose(z[:, :, 0], 0.9 * x[:, :, 0] + s * eps)


def test_split_disturbances_rows_state_first_time_major():
    model = get_model("sep_d1_p2")  # p = 2, d = 1
    T, K = 3, 2
    matrix = np.arange((2 + 1) * T * K, dtype=float).reshape((2 + 1) * T, K)
    eta, eps = model.split_disturbances(matrix, T)
    assert eta.shape == (K, T, 2) and eps.shape == (K, T, 1)
    # rows 0..pT-1 are eta_1..eta_T with p entries per step, then eps
    assert eta[1, 0, 0] == matrix[0, 1] and eta[1, 0, 1] == matrix[1, 1]
    assert eta[0, 2, 1] == matrix[5, 0]
    assert eps[0, 0, 0] == matrix[6, 0] and eps[1, 2, 0] == matrix[8, 1]
    with pytest.raises(ValueError, match=r"\(d\+p\)T = 9 rows"):
        model.split_disturbances(matrix[:-1], T)


def test_initial_states_for_d_not_p():
    z = np.arange(12, dtype=float).reshape(2, 3, 2)
    x = get_model("sep_d2_p1").initial_states(np.array([0.9, 0.9, 0.9]), z)
    assert np.allclose(x[..., 0], z.mean(axis=2))
    z1 = np.arange(6, dtype=float).reshape(2, 3, 1)
    x2 = get_model("sep_d1_p2").initial_states(np.array([0.6, 0.5, 0.9, 0.9]), z1)
    assert (
        x2.shape == (2, 3, 2)
        and np.allclose(x2[..., 0], z1[..., 0])
        and np.allclose(x2[..., 1], z1[..., 0])
    )
    z3 = np.ones((2, 3, 1))
    assert np.allclose(get_model("same").initial_states(np.array([0.9]), z3), z3)


def test_prior_bounds_follow_the_paper():
    same = get_model("same")
    b = same.prior_bounds([0.9])
    assert b.lower.tolist() == [0.0] and b.upper.tolist() == [1.0]  # Eq. (3)
    b = same.prior_bounds([-0.5])
    assert b.lower.tolist() == [-1.0] and b.upper.tolist() == [0.0]
    b = same.prior_bounds([0.9], "unrestricted")
    assert b.lower.tolist() == [-1.0] and b.upper.tolist() == [1.0]
    rw = get_model("sep_ranwalk").prior_bounds([0.9])
    assert rw.lower.tolist() == [0.0] and rw.upper[0] == np.inf  # Eq. (14)
    sep = get_model("sep").prior_bounds([0.9, 0.9], {"a": "unrestricted"})
    assert sep.lower.tolist() == [-1.0, 0.0] and sep.variants == ("unrestricted", "restricted")


@pytest.mark.parametrize(
    "prior, words",
    [
        ("flat", ["unknown prior variant 'flat'", "'a'"]),
        ("half_line", ["'half_line' is not allowed", "'a'", "same"]),
        ({"q": "restricted"}, ["['q']", "parameters are ['a']"]),
    ],
)
def test_prior_errors_name_the_problem(prior, words):
    with pytest.raises(ValueError) as err:
        get_model("same").prior_bounds([0.9], prior)
    for w in words:
        assert w in str(err.value)


def test_prior_sign_of_zero_true_value_is_an_error():
    with pytest.raises(ValueError, match="'a'.*which is 0"):
        get_model("same").prior_bounds([0.0])


@pytest.mark.parametrize(
    "slug, omega, x0, words",
    [
        ("same", [1.2], 8, ["a=1.2", "|a| < 1"]),
        ("sep_mult", [-0.5], 8, ["a=-0.5", "> 0"]),
        ("sep_d1_p2", [0.8, 0.7, 0.9, 0.9], [8, 8], ["violate the constraint", "sep_d1_p2"]),
        ("sep_d1_p2", [0.6, 0.5, 0.9, 0.9], 8, ["x0 must have 2 component(s)"]),
        ("sep", {"a": 0.9}, 8, ["missing ['b']"]),
        ("same", [float("nan")], 8, ["finite"]),
    ],
)
def test_check_true_values_messages(slug, omega, x0, words):
    problems = get_model(slug).check_true_values(omega, x0)
    assert problems, "expected a problem"
    text = " ".join(problems)
    for w in words:
        assert w in text


@pytest.mark.parametrize("slug", sorted(MODELS))
def test_paper_true_values_are_valid(slug):
    omega, x0 = TRUE[slug]
    assert get_model(slug).check_true_values(omega, x0) == []


def test_unknown_model_lists_the_known_ones():
    with pytest.raises(ValueError, match="known models"):
        get_model("nope")


@pytest.mark.parametrize(
    ("slug", "omega", "x0", "T", "words"),
    [
        ("sep_ranwalk", {"a": 1e6}, [8.0], 4, "true value a=1e+06 is too large: |a| <= 10000"),
        ("same", {"a": 0.5}, [1e300], 4, "true value x0=1e+300 is too large"),
        ("sep_mult", {"a": 200.0}, [8.0], 100, "reach |x_t| or |z_t| = 20008 within T=100 steps"),
    ],
)
def test_extreme_true_values_are_refused_with_the_value(slug, omega, x0, T, words):
    (msg,) = get_model(slug).check_true_values(omega, x0, T=T)
    assert words in msg
    assert "double precision" in msg


def test_extreme_values_stop_the_config_before_any_job():
    from ssmobs.config.validation import ConfigError, validate

    config = {
        "scenarios": [
            {"name": "rw", "model": "sep_ranwalk", "omega": {"a": 1e6}, "x0": 8, "T": 4, "K": 2}
        ]
    }
    with pytest.raises(ConfigError, match=r"a=1e\+06 is too large"):
        validate(config)


def test_an_interval_prior_sets_the_bounds_as_given():
    """Issue 47: [lower, upper] per parameter, either bound infinite, whatever the model's
    allowed variants (the model check compares it with Stan's bounds)."""
    sv = get_model("stoch_vol")
    b = sv.prior_bounds([0.9, 0.5], {"sigma": [0.0, np.inf], "phi": (-np.inf, np.inf)})
    assert b.lower.tolist() == [-np.inf, 0.0] and b.upper.tolist() == [np.inf, np.inf]
    assert b.variants == ("interval(-inf, inf)", "interval(0, inf)")
    b = get_model("same").prior_bounds([0.9], {"a": [0.5, 0.95]})
    assert (b.lower[0], b.upper[0]) == (0.5, 0.95)
    assert get_model("same").check_true_values({"a": 0.3}, 8, {"a": [0.5, 0.95]}) == [
        "true value a=0.3 lies outside the support (0.5, 0.95) of its prior 'interval(0.5, 0.95)'"
    ]


@pytest.mark.parametrize(
    "interval, words",
    [
        ([1.0, 0.0], ["'a'", "lower < upper", "[1.0, 0.0]"]),
        ([0.0, 1.0, 2.0], ["'a'", "two numbers"]),
        (["x", 1.0], ["'a'", "two numbers"]),
        ([np.nan, 1.0], ["'a'", "lower < upper"]),
    ],
)
def test_a_bad_interval_prior_names_the_problem(interval, words):
    with pytest.raises(ValueError) as err:
        get_model("same").prior_bounds([0.9], {"a": interval})
    for w in words:
        assert w in str(err.value)
