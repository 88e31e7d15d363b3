"""The symmetries found from a model's terms (issue 60): one test model per class, the
shipped models, and every found map checked against independent NumPy code."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest
from cubic_sensor_model import CubicSensor
from growth_model import Growth
from phase_model import PhaseTracking
from ricker_model import Ricker
from ssmobs.models import get_model
from ssmobs.models.symmetries import model_symmetries, preserves_box
from two_component_model import TwoComponents
from two_gain_model import TwoGains

pytestmark = pytest.mark.unit

T = 5


# --------------------------------------------------------------- independent -2 log pi
def _split(theta, m, p):
    return theta[:, :m], theta[:, m:].reshape(theta.shape[0], T + 1, p)


def growth_density(theta, z):
    (w, x) = _split(theta, 2, 1)
    a, b = w[:, :1], w[:, 1:]
    xp, xt = x[:, :-1, 0], x[:, 1:, 0]
    return np.sum((z - xt**2 / 20) ** 2 + (xt - a * xp - b * xp / (1 + xp**2)) ** 2, axis=1)


def cubic_density(theta, z):
    w, x = _split(theta, 2, 1)
    b, a = w[:, :1], w[:, 1:]
    xp, xt = x[:, :-1, 0], x[:, 1:, 0]
    return np.sum((z - b * xt**3) ** 2 + (xt - a * xp) ** 2, axis=1)


def two_component_density(theta, z):
    w, x = _split(theta, 2, 2)
    xp, xt = x[:, :-1], x[:, 1:]
    trans = (xt[..., 0] - w[:, :1] * xp[..., 0]) ** 2 + (xt[..., 1] - w[:, 1:] * xp[..., 1]) ** 2
    return np.sum((z - xt[..., 0] - xt[..., 1]) ** 2 + trans, axis=1)


def phase_density(theta, z):
    w, x = _split(theta, 2, 1)
    mu, b = w[:, :1], w[:, 1:]
    xp, xt = x[:, :-1, 0], x[:, 1:, 0]
    return np.sum((z - b * np.sin(xt)) ** 2 + (xt - xp - mu) ** 2, axis=1) / 0.09


def ricker_density(theta, z):
    w, x = _split(theta, 3, 1)
    a, b, c = w[:, :1], w[:, 1:2], w[:, 2:]
    xp, xt = x[:, :-1, 0], x[:, 1:, 0]
    return np.sum((z - c * np.exp(xt)) ** 2 + (xt - xp - a + b * np.exp(xp)) ** 2, axis=1)


def sep_d1_p2_density(theta, z):
    w, x = _split(theta, 4, 2)
    a, b, c, d = (w[:, i : i + 1] for i in range(4))
    xp, xt = x[:, :-1], x[:, 1:]
    s2 = 1 - a**2 - b**2
    obs = (z - a * xt[..., 0] - b * xt[..., 1]) ** 2 / s2 + np.log(s2)
    trans = (xt[..., 0] - c * xp[..., 0]) ** 2 / (1 - c**2) + np.log(1 - c**2)
    trans += (xt[..., 1] - d * xp[..., 1]) ** 2 / (1 - d**2) + np.log(1 - d**2)
    return np.sum(obs + trans, axis=1)


def sep_d2_p1_density(theta, z2):
    w, x = _split(theta, 3, 1)
    a, b, c = w[:, :1], w[:, 1:2], w[:, 2:]
    xp, xt = x[:, :-1, 0], x[:, 1:, 0]
    obs = (z2[..., 0] - a * xt) ** 2 / (1 - a**2) + np.log(1 - a**2)
    obs += (z2[..., 1] - b * xt) ** 2 / (1 - b**2) + np.log(1 - b**2)
    return np.sum(obs + (xt - c * xp) ** 2 / (1 - c**2) + np.log(1 - c**2), axis=1)


def sep_like_density(obs_coef, trans_coef, m):
    """Sep (b x, a x_prev) and ranWalk (a x, x_prev) written out; -2 log pi."""

    def density(theta, z):
        w, x = _split(theta, m, 1)
        xp, xt = x[:, :-1, 0], x[:, 1:, 0]
        h, f = obs_coef(w), trans_coef(w)
        vh = np.where(m == 2, 1 - h**2, 1.0)
        vf = np.where(m == 2, 1 - f**2, 1.0)
        obs = (z - h * xt) ** 2 / vh + np.log(vh)
        return np.sum(obs + (xt - f * xp) ** 2 / vf + np.log(vf), axis=1)

    return density


def _points(m, p, rng, n=20, w_scale=0.45):
    w = rng.uniform(-w_scale, w_scale, (n, m)) + np.sign(rng.uniform(-1, 1, (n, m))) * 0.1
    return np.concatenate([w, rng.normal(0, 1.2, (n, (T + 1) * p))], axis=1)


def _assert_invariant(model, density, m, p, d=1):
    rng = np.random.default_rng(7)
    theta = _points(m, p, rng)
    z = rng.normal(0, 1.5, (theta.shape[0], T) if d == 1 else (theta.shape[0], T, d))
    base = density(theta, z)
    assert np.all(np.isfinite(base))
    found = model_symmetries(model)
    for sym in found.discrete:
        image = sym.apply(model, theta)
        assert np.allclose(density(image, z), base, rtol=1e-10, atol=1e-10), sym.name
        assert np.allclose(sym.apply_inverse(model, image), theta, atol=1e-12), sym.name
        # a map that is not the identity moves some point
        assert not np.allclose(image, theta)
    return found


# --------------------------------------------------------------- one model per class
def test_sign_mirror_of_the_cubic_sensor_and_the_growth_model():
    cubic = _assert_invariant(CubicSensor(), cubic_density, 2, 1)
    assert [(s.name, s.kind, s.infinite_order) for s in cubic.discrete] == [
        ("(b, x) -> (-b, -x)", "sign", False)
    ]
    growth = _assert_invariant(Growth(), growth_density, 2, 1)
    assert [(s.name, s.kind) for s in growth.discrete] == [("x -> -x", "sign")]
    assert cubic.ridges == () and growth.ridges == ()


def test_block_swap_of_two_components_seen_through_their_sum():
    found = _assert_invariant(TwoComponents(), two_component_density, 2, 2)
    assert [(s.name, s.kind) for s in found.discrete] == [
        ("swap (a1, x_1) <-> (a2, x_2)", "permutation")
    ]
    (swap,) = found.discrete
    theta = np.arange(2 + 2 * (T + 1), dtype=float)[None]
    image = swap.apply(TwoComponents(), theta)
    assert image[0, :2].tolist() == [1.0, 0.0]
    assert image[0, 2:4].tolist() == [3.0, 2.0]  # x0's components swapped


def test_periodic_shift_and_reflection_of_phase_tracking():
    model = PhaseTracking()
    found = _assert_invariant(model, phase_density, 2, 1)
    by_name = {s.name: s for s in found.discrete}
    shift = by_name["x -> x + 2*pi"]
    assert shift.kind == "translation" and shift.infinite_order
    reflection = by_name["(mu, x) -> (-mu, pi - x)"]
    assert reflection.kind == "reflection" and not reflection.infinite_order
    theta = np.zeros((1, model.n_theta(T)))
    assert np.allclose(shift.apply(model, theta)[0, 2:], 2 * math.pi)
    assert np.allclose(reflection.apply(model, theta)[0, 2:], math.pi)
    # the images for the multi-start: a translation in both directions, the others once
    n_images = len(found.discrete) + sum(s.infinite_order for s in found.discrete)
    images = found.images(model, theta)
    assert len(images) == n_images
    assert any(np.allclose(im[0, 2:], -2 * math.pi) for im in images)
    # the prior mu on the line, b on (0, inf): only maps keeping b > 0 keep the support
    bounds = model.prior_bounds({"mu": 0.5, "b": 1.0}, {"mu": [-math.inf, math.inf]})
    kept = {s.name for s in found.discrete if preserves_box(s, bounds)}
    assert kept == {"x -> x + 2*pi", "(mu, x) -> (-mu, pi - x)"}


def test_scaling_and_exact_ridge_of_the_ricker_model():
    model = Ricker()
    found = model_symmetries(model)
    assert found.discrete == ()
    (ridge,) = found.ridges
    assert ridge.name == "(b, c, x) -> (b e^-s, c e^-s, x + s)"
    assert ridge.scaling == (0.0, -1.0, -1.0, 0.0)
    assert ridge.translation == (0.0, 0.0, 0.0, 1.0)
    assert ridge.unbounded == ("x0",)
    rng = np.random.default_rng(3)
    theta = np.concatenate([rng.uniform(0.2, 1.5, (10, 3)), rng.normal(0, 1, (10, T + 1))], 1)
    z = rng.normal(2, 1, (10, T))
    base = ricker_density(theta, z)
    for s in (-3.0, -0.5, 2.0):
        moved = ridge.follow(model, theta, s)
        assert np.allclose(moved[:, 1:3], theta[:, 1:3] * math.exp(-s))
        assert np.allclose(moved[:, 3:], theta[:, 3:] + s)
        assert np.allclose(ricker_density(moved, z), base, rtol=1e-10)
    # a direction that is not a ridge changes the density
    nudged = theta.copy()
    nudged[:, 3:] += 0.5
    assert not np.allclose(ricker_density(nudged, z), base)


def two_gain_density(theta, z):
    w, x = _split(theta, 3, 1)
    a, bc = w[:, :1], w[:, 1:2] * w[:, 2:]
    xp, xt = x[:, :-1, 0], x[:, 1:, 0]
    return np.sum((z - bc * xt) ** 2 + (xt - a * xp) ** 2, axis=1)


def test_scaling_ridge_of_two_gains_that_moves_no_state():
    model = TwoGains()
    found = _assert_invariant(model, two_gain_density, 3, 1)
    (ridge,) = found.ridges
    assert ridge.name == "(b, c) -> (b e^s, c e^-s)"
    assert ridge.scaling == (0.0, 1.0, -1.0, 0.0) and ridge.translation == (0.0,) * 4
    assert ridge.unbounded == ()  # x0 does not move
    rng = np.random.default_rng(4)
    theta = _points(3, 1, rng)
    z = rng.normal(0, 1.5, (theta.shape[0], T))
    for s in (-2.0, 1.5):
        moved = ridge.follow(model, theta, s)
        assert np.allclose(moved[:, 1] * moved[:, 2], theta[:, 1] * theta[:, 2])
        assert np.allclose(two_gain_density(moved, z), two_gain_density(theta, z))
    # the swap b <-> c and the sign maps are discrete symmetries besides
    assert "swap b <-> c" in {s.name for s in found.discrete}


# --------------------------------------------------------------- the shipped models
SHIPPED = {
    "same": set(),
    "sep": {"(b, x) -> (-b, -x)"},
    "sep_d2_p1": {"(a, b, x) -> (-a, -b, -x)"},
    "sep_d1_p2": {
        "swap (a, c, x_1) <-> (b, d, x_2)",
        "(a, x_1) -> (-a, -x_1)",
        "(b, x_2) -> (-b, -x_2)",
        "(a, b, x_1, x_2) -> (-a, -b, -x_1, -x_2)",
        "(a, b, c, d, x_1, x_2) -> (b, -a, d, c, x_2, -x_1)",
        "(a, b, c, d, x_1, x_2) -> (-b, a, d, c, -x_2, x_1)",
        "(a, b, c, d, x_1, x_2) -> (-b, -a, d, c, -x_2, -x_1)",
    },
    "sep_ranwalk": {"(a, x) -> (-a, -x)"},
    "sep_mult": set(),
    "stoch_vol": set(),
}


@pytest.mark.parametrize("slug", sorted(SHIPPED))
def test_shipped_models_have_exactly_their_true_symmetries(slug):
    model = get_model(slug)
    start = time.process_time()
    found = model_symmetries(model)
    assert time.process_time() - start < 10.0
    assert {s.name for s in found.discrete} == SHIPPED[slug]
    assert found.ridges == () and found.unconfirmed == ()
    assert model_symmetries(model) is found  # memoised
    # the sign maps change the sign of a parameter: none keeps the paper's restricted box
    bounds = model.prior_bounds(model.omega_array([0.5] * model.n_params), None)
    kept = [s.name for s in found.discrete if preserves_box(s, bounds)]
    assert kept == (["swap (a, c, x_1) <-> (b, d, x_2)"] if slug == "sep_d1_p2" else [])


def test_found_maps_of_shipped_models_agree_with_independent_code():
    sep = sep_like_density(lambda w: w[:, 1:2], lambda w: w[:, :1], 2)
    ranwalk = sep_like_density(lambda w: w[:, :1], lambda w: np.ones_like(w[:, :1]), 1)
    _assert_invariant(get_model("sep"), sep, 2, 1)
    _assert_invariant(get_model("sep_ranwalk"), ranwalk, 1, 1)
    _assert_invariant(get_model("sep_d2_p1"), sep_d2_p1_density, 3, 1, d=2)
    found = _assert_invariant(get_model("sep_d1_p2"), sep_d1_p2_density, 4, 2)
    assert len(found.discrete) == 7  # with the identity, the group of order 8
