"""The Stan programs stan/<slug>.stan give the same log density as the Python model.

For every model (and prior variants with finite and infinite bounds), PyStan's
``log_prob(unconstrain_pars(theta), adjust_transform=False)`` (the model block alone) must
equal :func:`ssmobs.models.log_posterior.log_posterior` up to one additive constant at
random points inside the support.  Needs the compiled programs (the first run compiles
each one, about a minute each; later runs find them in the httpstan cache).
"""

from __future__ import annotations

import zlib

import numpy as np
import pytest
from ssmobs.models import get_model
from ssmobs.models.log_posterior import log_posterior
from ssmobs.stan_backends import stan_file
from ssmobs.stan_backends.pystan import PyStanBackend

# every test builds its program with PyStan (`make test-slow`)
pytestmark = [pytest.mark.stan, pytest.mark.pystan]

T = 7
N_POINTS = 6
RTOL = 1e-8

# (slug, true Omega, prior variant(s)); the priors cover negative, mixed and infinite bounds
CASES = [
    ("same", {"a": 0.9}, None),
    ("same", {"a": -0.5}, "unrestricted"),
    ("sep", {"a": 0.9, "b": 0.9}, None),
    ("sep", {"a": 0.6, "b": -0.7}, {"a": "unrestricted"}),
    ("sep_d2_p1", {"a": 0.8, "b": -0.6, "c": 0.7}, None),
    ("sep_d1_p2", {"a": 0.5, "b": 0.6, "c": 0.8, "d": 0.6}, None),
    ("sep_d1_p2", {"a": -0.5, "b": 0.4, "c": 0.8, "d": -0.6}, "unrestricted"),
    ("sep_d1_p2", {"a": 0.3, "b": -0.6, "c": 0.5, "d": 0.6}, {"a": "unrestricted"}),
    ("sep_ranwalk", {"a": 0.5}, None),  # half line (0, inf)
    ("sep_ranwalk", {"a": -0.5}, None),  # half line (-inf, 0)
    ("sep_ranwalk", {"a": 0.5}, "unrestricted"),
    ("sep_mult", {"a": 0.5}, None),  # half line (0, inf)
    ("sep_mult", {"a": 0.5}, "restricted"),
]


def _ids(case):
    slug, omega, prior = case
    return f"{slug}-{'_'.join(f'{k}{v:g}' for k, v in omega.items())}-{prior}"


def _random_omega(model, bounds, rng):
    """A point strictly inside the prior box and the model constraints."""
    lo = np.where(np.isfinite(bounds.lower), bounds.lower, bounds.upper - 3.0)
    hi = np.where(np.isfinite(bounds.upper), bounds.upper, bounds.lower + 3.0)
    for _ in range(1000):
        omega = lo + (hi - lo) * rng.uniform(0.05, 0.95, size=lo.shape)
        if model.slug == "sep_d1_p2" and not omega[0] ** 2 + omega[1] ** 2 < 0.95:
            continue
        return omega
    raise AssertionError("no point found")


def _stan_point(model, theta, T):
    m, p = model.n_params, model.state_dim
    omega, states = theta[:m], theta[m:].reshape(T + 1, p)
    point = {name: float(omega[i]) for i, name in enumerate(model.param_names)}
    if p == 1:
        point["x0"] = float(states[0, 0])
        point["x"] = states[1:, 0].tolist()
    else:
        point["x0"] = states[0].tolist()
        point["x"] = states[1:].tolist()  # matrix[T, 2], row t = x_t
    return point


@pytest.fixture(scope="module")
def backend():
    return PyStanBackend()


@pytest.mark.parametrize("case", CASES, ids=_ids)
def test_log_density_matches_python(backend, case):
    import stan

    slug, omega_true, prior = case
    model = get_model(slug)
    rng = np.random.default_rng(zlib.crc32(_ids(case).encode()))
    x0_true = np.full(model.state_dim, 8.0 if slug != "sep_mult" else 5.0)
    eta = rng.standard_normal((1, T, model.state_dim))
    eps = rng.standard_normal((1, T, model.obs_dim))
    _, z = model.simulate(model.omega_array(omega_true), x0_true, eta, eps)
    z = z[0]
    bounds = model.prior_bounds(omega_true, prior)
    data = model.stan_data(z, bounds)
    code = stan_file(slug).read_text()

    py, st = [], []
    with backend.session(stan_file(slug)):
        post = stan.build(code, data=data)
        for _ in range(N_POINTS):
            omega = _random_omega(model, bounds, rng)
            states = x0_true + rng.normal(0.0, 1.0, size=(T + 1, model.state_dim))
            theta = np.concatenate([omega, states.reshape(-1)])
            upars = post.unconstrain_pars(_stan_point(model, theta, T))
            # the unconstrained point maps back to the same Omega
            back = np.asarray(post.constrain_pars(upars))
            assert back[: model.n_params] == pytest.approx(omega, rel=1e-10, abs=1e-12)
            py.append(float(log_posterior(model, theta, z, bounds)))
            st.append(post.log_prob(upars, adjust_transform=False))
    py, st = np.array(py), np.array(st)
    assert np.all(np.isfinite(py)) and np.all(np.isfinite(st))
    diff = st - py
    scale = np.maximum(1.0, np.abs(py))
    assert np.all(np.abs(diff - diff[0]) <= RTOL * scale), (diff, py)


def test_p2_state_layout(backend):
    """x is matrix[T, 2] with row t = x_t: Stan's flat (column-major) names say so."""
    import stan

    model = get_model("sep_d1_p2")
    omega = {"a": 0.5, "b": 0.6, "c": 0.8, "d": 0.6}
    bounds = model.prior_bounds(omega)
    data = model.stan_data(np.zeros((3, 1)), bounds)
    with backend.session(stan_file("sep_d1_p2")):
        post = stan.build(stan_file("sep_d1_p2").read_text(), data=data)
        point = {
            "a": 0.1,
            "b": 0.2,
            "c": 0.3,
            "d": 0.4,
            "x0": [10.0, 20.0],
            "x": [[11.0, 21.0], [12.0, 22.0], [13.0, 23.0]],
        }
        flat = post.constrain_pars(post.unconstrain_pars(point))
    names = post.constrained_param_names
    values = dict(zip(names, flat))
    assert values["x.2.1"] == pytest.approx(12.0) and values["x.2.2"] == pytest.approx(22.0)
    assert values["x0.2"] == pytest.approx(20.0)
    assert dict(zip(post.param_names, post.dims))["x"] == [3, 2]


def test_sep_d1_p2_support_is_the_disk(backend):
    """(a, b) outside a^2 + b^2 < 1 cannot be given to Stan; inside near the rim it can."""
    import stan

    model = get_model("sep_d1_p2")
    omega = {"a": 0.5, "b": 0.6, "c": 0.8, "d": 0.6}
    data = model.stan_data(np.zeros((2, 1)), model.prior_bounds(omega))
    base = {"c": 0.3, "d": 0.4, "x0": [0.0, 0.0], "x": [[1.0, 1.0], [2.0, 2.0]]}
    with backend.session(stan_file("sep_d1_p2")):
        post = stan.build(stan_file("sep_d1_p2").read_text(), data=data)
        upars = post.unconstrain_pars({**base, "a": 0.7, "b": 0.71})  # 0.9941 < 1
        back = post.constrain_pars(upars)
        assert back[:2] == pytest.approx([0.7, 0.71])
        with pytest.raises(RuntimeError):
            post.unconstrain_pars({**base, "a": 0.7, "b": 0.72})  # 1.0084 > 1


@pytest.mark.parametrize(
    "slug,bad",
    [
        ("same", {"a_lower": 1.0, "a_upper": 2.0}),  # prior misses (-1, 1)
        ("sep_mult", {"a_lower": -2.0, "a_upper": -1.0}),  # prior misses a > 0
        ("sep_d1_p2", {"a_lower": 0.9, "a_upper": 1.0, "b_lower": 0.5, "b_upper": 1.0}),
    ],
)
def test_empty_support_is_rejected_at_data_time(backend, slug, bad):
    import stan

    model = get_model(slug)
    omega = {n: 0.5 for n in model.param_names}
    data = {**model.stan_data(np.ones((4, model.obs_dim)), model.prior_bounds(omega)), **bad}
    with backend.session(stan_file(slug)):
        with pytest.raises(RuntimeError, match="empty support"):
            stan.build(stan_file(slug).read_text(), data=data)


def test_sep_d1_p2_jacobian_keeps_prior_flat(backend):
    """With the Jacobian (as when sampling), the density on (a, b, c, d) is the flat prior:
    log_prob(u, adjust_transform=True) - log_prob(u, False) = log|det d(a,b,c,d)/du|."""
    import stan

    model = get_model("sep_d1_p2")
    omega = {"a": 0.5, "b": -0.6, "c": 0.8, "d": 0.6}
    data = model.stan_data(
        np.array([[0.3], [-0.2]]), model.prior_bounds(omega, {"a": "unrestricted"})
    )
    rng = np.random.default_rng(7)
    with backend.session(stan_file("sep_d1_p2")):
        post = stan.build(stan_file("sep_d1_p2").read_text(), data=data)
        for _ in range(3):
            u = rng.uniform(-2, 2, size=4 + 2 + 4).tolist()
            h = 1e-6
            jac = np.empty((4, 4))
            for k in range(4):
                up, dn = list(u), list(u)
                up[k] += h
                dn[k] -= h
                jac[:, k] = (
                    np.array(post.constrain_pars(up)[:4]) - np.array(post.constrain_pars(dn)[:4])
                ) / (2 * h)
            a, b = post.constrain_pars(u)[:2]
            assert a**2 + b**2 < 1 and b < 0
            log_det = np.log(abs(np.linalg.det(jac)))
            adjusted = post.log_prob(u, adjust_transform=True)
            plain = post.log_prob(u, adjust_transform=False)
            assert adjusted - plain == pytest.approx(log_det, abs=1e-6)
