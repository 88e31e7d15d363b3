"""Joint MAP (Sec. III.B): optimiser, checks, summaries, profile posterior.

The arrow/banded linear algebra it uses is tested in test_banded_linalg.py.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from scipy.optimize import minimize
from ssmobs.joint_map.barrier import LogBarrier
from ssmobs.joint_map.checks import STATUSES, ridge_check
from ssmobs.joint_map.driver import initial_theta, joint_map, joint_map_summary
from ssmobs.joint_map.problem import JointMapProblem
from ssmobs.joint_map.settings import JointMapSettings
from ssmobs.models import get_model
from ssmobs.models.base import PriorBounds, StateSpaceModel
from ssmobs.models.log_posterior import log_posterior, neg2_log_posterior
from ssmobs.reports.profile_posterior import profile_posterior

pytestmark = pytest.mark.unit


def design(slug, omega, x0, T, K, seed=0):
    model = get_model(slug)
    rng = np.random.default_rng(seed)
    matrix = rng.standard_normal(((model.obs_dim + model.state_dim) * T, K))
    x, z = model.design_trajectories(omega, x0, matrix, T)
    return model, x, z


# --------------------------------------------------------------------------- optimiser and checks
@pytest.fixture(scope="module")
def same_t20():
    model, x, z = design("same", [0.9], [8.0], T=20, K=12, seed=1)
    bounds = model.prior_bounds([0.9])
    return model, z, bounds, joint_map(JointMapProblem(model, z, bounds, [0.9], [8.0]))


def test_same_all_ok_and_checks_hold(same_t20):
    model, z, bounds, res = same_t20
    assert (res.status == "ok").all()
    assert np.all(res.grad_max < 1e-5)
    v, g, H = neg2_log_posterior(model, res.theta_hat, z, order=2)
    assert np.allclose(res.neg2_log_post, v)
    assert np.allclose(np.abs(g).max(axis=1), res.grad_max)
    lam = np.linalg.eigvalsh(H)
    assert np.all(lam[:, 0] > 0)
    assert np.allclose(res.eig_ratio, lam[:, 0] / lam[:, -1], rtol=1e-6)
    # LVar = -H_pi^{-1}_jj = 2 (H_{-2pi}^{-1})_jj  (Sec. II.B)
    lvar = 2 * np.diagonal(np.linalg.inv(H), axis1=1, axis2=2)
    assert np.allclose(res.local_variance, lvar, rtol=1e-8)
    assert np.all(res.iterations > 0) and np.all(res.reason == "")


def test_same_matches_scipy_from_the_paper_start(same_t20):
    """An independent optimiser (SciPy trust-exact, same start) finds the same joint MAP."""
    model, z, bounds, res = same_t20
    theta0 = initial_theta(model, z, np.array([0.9]), np.array([8.0]))
    for k in range(3):

        def f(t):
            return neg2_log_posterior(model, t, z[k], bounds, 0)[0]

        def jac(t):
            return neg2_log_posterior(model, t, z[k], None, 1)[1]

        def hess(t):
            return neg2_log_posterior(model, t, z[k], None, 2)[2]

        ref = minimize(
            f,
            theta0[k],
            jac=jac,
            hess=hess,
            method="trust-exact",
            options={"gtol": 1e-10, "maxiter": 500},
        )
        assert np.abs(ref.x - res.theta_hat[k]).max() < 1e-6


@pytest.mark.parametrize(
    "slug, omega, x0, T",
    [
        ("sep", [0.9, 0.9], [8.0], 30),
        ("sep_d2_p1", [0.9, 0.9, 0.9], [8.0], 20),
        ("sep_mult", [0.9], [8.0], 10),
    ],
)
def test_local_maxima_match_scipy_bfgs(slug, omega, x0, T):
    """Where the joint posterior has several local maxima, SciPy's BFGS (gradient only)
    started next to our optimum converges to the same point, to 1e-6."""
    model, x, z = design(slug, omega, x0, T=T, K=6, seed=5)
    bounds = model.prior_bounds(omega)
    res = joint_map(JointMapProblem(model, z, bounds, omega, x0))
    ok = np.flatnonzero(res.status == "ok")
    assert ok.size >= 2
    for k in ok[:2]:

        def f(t):
            return neg2_log_posterior(model, t, z[k], bounds, 0)[0]

        def jac(t):
            return neg2_log_posterior(model, t, z[k], None, 1)[1]

        start = res.theta_hat[k] + 1e-3 * np.random.default_rng(int(k)).standard_normal(
            res.theta_hat.shape[1]
        )
        ref = minimize(f, start, jac=jac, method="BFGS", options={"gtol": 1e-9, "maxiter": 2000})
        assert np.abs(ref.x - res.theta_hat[k]).max() < 1e-6


def test_ranwalk_t4_ridge_is_never_ok():
    """(Sep, d=p=1, ranWalk), T = 4: a ridge of variable height (Fig. 4), |K^max| = 0."""
    model, x, z = design("sep_ranwalk", [0.9], [8.0], T=4, K=20, seed=2)
    res = joint_map(
        JointMapProblem(
            model, z, model.prior_bounds([0.9]), [0.9], [8.0], JointMapSettings(max_newton_iter=60)
        )
    )
    assert not (res.status == "ok").any()
    assert set(res.status) <= set(STATUSES) - {"ok", "failed"}
    assert all(r for r in res.reason)


class ProductRidge(StateSpaceModel):
    """Test model with a ridge of constant height: only a * b is identified."""

    slug = "test_product_ridge"
    title = "Z_t = a b X_t + eps_t, X_t = X_{t-1} / 2 + 4 + eta_t"
    obs_dim = 1
    state_dim = 1
    param_names = ("a", "b")
    default_prior = {"a": "unrestricted", "b": "unrestricted"}
    allowed_priors = {"a": ("unrestricted",), "b": ("unrestricted",)}

    def obs_term(self, omega, x, z):
        (a, b), (xt,), (zt,) = omega, x, z
        return (zt - a * b * xt) ** 2

    def trans_term(self, omega, x_prev, x):
        return (x[0] - x_prev[0] / 2 - 4) ** 2

    def simulate(self, omega, x0, eta, eps):
        K, T, _ = eta.shape
        x = np.empty((K, T, 1))
        prev = np.full(K, x0[0])
        for t in range(T):
            prev = prev / 2 + 4 + eta[:, t, 0]
            x[:, t, 0] = prev
        return x, omega[0] * omega[1] * x + eps


def test_constant_height_ridge_is_detected():
    model = ProductRidge()
    T, K = 30, 4
    rng = np.random.default_rng(3)
    x, z = model.design_trajectories([1.0, 0.8], [8.0], rng.standard_normal((2 * T, K)), T)
    bounds = PriorBounds(np.array([0.2, 0.2]), np.array([5.0, 5.0]), ("x", "x"))
    res = joint_map(JointMapProblem(model, z, bounds, [1.0, 0.8], [8.0]))
    assert not (res.status == "ok").any()
    assert set(res.status) <= {"ridge", "not-positive-definite"}
    assert np.all(res.eig_ratio < 1e-5)
    # the ridge re-optimisation itself: shifting along the ridge moves the optimum
    v = np.zeros_like(res.theta_hat)
    v[:, 0], v[:, 1] = res.theta_hat[:, 0], -res.theta_hat[:, 1]  # tangent of a b = const
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    f_hat = res.neg2_log_post
    moved, dist, dval = ridge_check(
        model, z, res.theta_hat, f_hat, v, LogBarrier(model, bounds), JointMapSettings()
    )
    assert moved.all() and np.all(dist > 1e-2)
    # why the location test (issue 12): on a ridge of constant height the re-optimisation
    # ends elsewhere at the same value of -2 pi, so the paper's "different value", read as
    # the objective value, would call this ridge a unique maximum
    assert np.all(dval <= 1e-8 * (1 + np.abs(f_hat)))
    by_value, _, _ = ridge_check(
        model,
        z,
        res.theta_hat,
        f_hat,
        v,
        LogBarrier(model, bounds),
        JointMapSettings(ridge_test="value"),
    )
    assert not by_value.any()


def test_small_ratio_at_a_unique_maximum_stays_ok(same_t20):
    """Forcing the ridge re-optimisation (r0 = 0.9): the optimum does not move -> ok."""
    model, z, bounds, res = same_t20
    forced = joint_map(
        JointMapProblem(model, z[:4], bounds, [0.9], [8.0], JointMapSettings(eig_ratio_min=0.9))
    )
    assert (forced.status == "ok").all()
    assert all("re-optimisation returned" in r for r in forced.reason)
    assert np.allclose(forced.theta_hat, res.theta_hat[:4])


def test_ridge_status_when_the_reoptimisation_moves(same_t20, monkeypatch):
    """Wiring of the last check: ratio < r0 and a moved re-optimisation give "ridge"."""
    import ssmobs.joint_map.checks as checks

    model, z, bounds, res = same_t20
    calls = []

    def fake(model_, z_, theta_, f_, v_, barrier_, settings_):
        calls.append(theta_.shape[0])
        assert np.allclose(np.linalg.norm(v_, axis=1), 1.0)
        n = theta_.shape[0]
        return np.ones(n, dtype=bool), np.full(n, 0.5), np.full(n, 0.25)

    monkeypatch.setattr(checks, "ridge_check", fake)
    out = joint_map(
        JointMapProblem(model, z[:3], bounds, [0.9], [8.0], JointMapSettings(eig_ratio_min=0.9))
    )
    assert calls == [3]
    assert (out.status == "ridge").all()
    assert all("moved 0.5" in r and "changed by 0.25" in r for r in out.reason)
    assert np.allclose(out.ridge_value_change, 0.25)
    assert np.isnan(joint_map_summary(out.to_frame(model, 20), model, [0.9], 8.0)["a_mean"])


def test_maximum_on_the_prior_boundary():
    """Same with a prior cut at a < 0.5 while the data say a ~ 0.9: maximum on the boundary."""
    model, x, z = design("same", [0.9], [8.0], T=20, K=4, seed=4)
    bounds = PriorBounds(np.array([0.0]), np.array([0.5]), ("restricted",))
    res = joint_map(JointMapProblem(model, z, bounds, [0.3], [8.0]))
    assert (res.status == "boundary").all()
    assert np.all(res.theta_hat[:, 0] > 0.499)
    assert all("boundary" in r or "barrier" in r for r in res.reason)


def test_sep_singular_edge_is_boundary():
    """(Sep, d=p=1): -2 pi -> -inf as b -> 1 with x_t = z_t / b (or a -> 1); runs that do not
    find an interior local maximum end at that edge and are classified boundary."""
    model, x, z = design("sep", [0.9, 0.9], [8.0], T=40, K=10, seed=2)
    bounds = model.prior_bounds([0.9, 0.9])
    res = joint_map(JointMapProblem(model, z, bounds, [0.9, 0.9], [8.0]))
    assert set(res.status) <= {"ok", "boundary"}
    edge = res.status == "boundary"
    assert edge.sum() >= 5
    assert np.all(res.theta_hat[edge, :2].max(axis=1) > 0.9999)
    # stopped before reaching boundary_tol: the descent towards the edge identifies it
    res2 = joint_map(
        JointMapProblem(
            model,
            z,
            bounds,
            [0.9, 0.9],
            [8.0],
            JointMapSettings(boundary_tol=1e-12, boundary_stop_tol=1e-12, max_newton_iter=30),
        )
    )
    assert any("still decreases towards the boundary" in r for r in res2.reason)
    assert not (res2.status[edge] == "ok").any()


def test_non_finite_data_is_recorded_not_raised():
    model, x, z = design("same", [0.9], [8.0], T=10, K=3, seed=6)
    z[1, 4, 0] = np.nan
    res = joint_map(JointMapProblem(model, z, model.prior_bounds([0.9]), [0.9], [8.0]))
    assert res.status[1] == "failed" and "non-finite" in res.reason[1]
    assert res.status[0] == "ok" and res.status[2] == "ok"
    assert res.to_frame(model, 10).loc[1, "reason"] != ""


def test_chunking_does_not_change_results_and_progress_counts(same_t20):
    model, z, bounds, res = same_t20

    class Counter:
        done = 0

        def update(self, n=1):
            Counter.done += n

    chunked = joint_map(
        JointMapProblem(model, z, bounds, [0.9], [8.0], JointMapSettings(chunk_size=5)),
        progress=Counter(),
    )
    assert Counter.done == z.shape[0]
    assert np.allclose(chunked.theta_hat, res.theta_hat, rtol=1e-12, atol=1e-12)
    assert (chunked.status == res.status).all()


def test_halvings_in_one_evaluation_give_the_same_bits_with_fewer_evaluations(monkeypatch):
    """The line search's halvings several at a time (``LINE_SEARCH_VALUES``) accept the step
    that one halving per evaluation accepts, to the bit, in every trajectory.  The data: a
    random set of the choice of K's size (Same, T = 4, K = 500) in which some trajectories
    backtrack tens of times per Newton step."""
    from ssmobs.joint_map import barrier

    model, x, z = design("same", [0.9], [8.0], T=4, K=500, seed=4)
    bounds = model.prior_bounds([0.9])
    evaluations: list[int] = []
    value_only = barrier.neg2_log_posterior

    def counted(model, theta, z, bounds=None, order=0):
        if order == 0:
            evaluations.append(theta.shape[0])
        return value_only(model, theta, z, bounds, order=order)

    monkeypatch.setattr(barrier, "neg2_log_posterior", counted)
    results, counts = {}, {}
    for values in (0, barrier.LINE_SEARCH_VALUES):  # 0: one halving per evaluation
        monkeypatch.setattr(barrier, "LINE_SEARCH_VALUES", values)
        evaluations.clear()
        results[values] = joint_map(JointMapProblem(model, z, bounds, [0.9], [8.0]))
        counts[values] = len(evaluations)
    one, many = results[0], results[barrier.LINE_SEARCH_VALUES]
    for name in ("theta_hat", "neg2_log_post", "grad_max", "local_variance", "eig_ratio"):
        a, b = getattr(one, name), getattr(many, name)
        assert np.array_equal(a.view(np.uint64), b.view(np.uint64)), name
    assert np.array_equal(one.iterations, many.iterations)
    assert (one.status == many.status).all() and (one.reason == many.reason).all()
    assert counts[barrier.LINE_SEARCH_VALUES] < counts[0] / 2, counts


def test_d2_p1_and_d1_p2_run():
    for slug, omega, x0 in [
        ("sep_d2_p1", [0.9, 0.9, 0.9], [8.0]),
        ("sep_d1_p2", [0.6, 0.5, 0.9, 0.9], [8.0, 8.0]),
    ]:
        model, x, z = design(slug, omega, x0, T=10, K=3, seed=7)
        res = joint_map(
            JointMapProblem(
                model, z, model.prior_bounds(omega), omega, x0, JointMapSettings(max_newton_iter=50)
            )
        )
        assert res.theta_hat.shape == (3, model.n_theta(10))
        assert set(res.status) <= set(STATUSES)
        frame = res.to_frame(model, 10)
        assert list(frame.columns[-2 * (model.n_params + model.state_dim) :]) == (
            model.theta_names(0) + [f"lvar_{c}" for c in model.theta_names(0)]
        )


def test_start_outside_support_raises():
    model, x, z = design("same", [0.9], [8.0], T=5, K=2)
    with pytest.raises(ValueError, match="not strictly inside"):
        joint_map(JointMapProblem(model, z, model.prior_bounds([0.9]), [-0.5], [8.0]))


# --------------------------------------------------------------------------- frame and summary
def test_to_frame_columns(same_t20):
    model, z, bounds, res = same_t20
    frame = res.to_frame(model, 20)
    assert list(frame.columns) == [
        "k",
        "status",
        "reason",
        "neg2_log_post",
        "eig_ratio",
        "grad_max",
        "iterations",
        "mu0",
        "ridge_value_change",
        "a",
        "x0",
        "lvar_a",
        "lvar_x0",
    ]
    assert frame["k"].tolist() == list(range(12))
    assert np.allclose(frame["x0"], res.theta_hat[:, 1])
    assert np.allclose(frame["lvar_a"], res.local_variance[:, 0])


def test_summary_on_a_hand_made_frame():
    model = get_model("same")
    frame = pd.DataFrame(
        {
            "status": ["ok", "ok", "gradient", "ok"],
            "a": [0.8, 1.0, 5.0, 0.9],
            "x0": [7.0, 9.0, 100.0, 8.0],
            "lvar_a": [0.1, 0.2, 9.0, 0.3],
            "lvar_x0": [1.0, 1.0, 9.0, 4.0],
        }
    )
    s = joint_map_summary(frame, model, [0.9], 8.0)
    assert s["K"] == 4 and s["K_max"] == 3 and s["ratio"] == 0.75
    assert s["n_ok"] == 3 and s["n_gradient"] == 1 and s["n_ridge"] == 0
    assert np.isclose(s["a_mean"], 0.9) and np.isclose(s["x0_mean"], 8.0)
    assert np.isclose(s["a_var"], 0.01)  # ddof = 1 (Table II)
    assert np.isclose(s["x0_var"], 1.0)
    assert np.isclose(s["a_mse"], 0.02 / 3) and np.isclose(s["x0_mse"], 2.0 / 3)
    assert np.isclose(s["a_lvar_mean"], 0.2) and np.isclose(s["x0_lvar_mean"], 2.0)
    empty = joint_map_summary(frame.assign(status="ridge"), model, [0.9], [8.0])
    assert empty["K_max"] == 0 and np.isnan(empty["a_mean"]) and np.isnan(empty["x0_var"])


def test_settings_validation_and_mapping():
    s = JointMapSettings.from_mapping({"grad_tol": 1e-6, "max_newton_iter": 50})
    assert s.grad_tol == 1e-6 and s.eig_ratio_min == 1e-5
    assert s.initial_mu(50) == 100.0
    with pytest.raises(ValueError, match="unknown joint-MAP setting"):
        JointMapSettings.from_mapping({"grad_tolerance": 1e-6})
    with pytest.raises(ValueError, match="grad_tol"):
        JointMapSettings(grad_tol=-1.0)
    with pytest.raises(ValueError, match="mu_factor"):
        JointMapSettings(mu_factor=1.5)
    with pytest.raises(ValueError, match="eigen_method"):
        JointMapSettings(eigen_method="qr")


# --------------------------------------------------------------------------- profile posterior
def test_profile_posterior_ranwalk_matches_inner_scipy():
    model, x, z = design("sep_ranwalk", [0.9], [8.0], T=4, K=1, seed=1)
    bounds = model.prior_bounds([0.9])
    a_vals = np.array([-0.2, 0.3, 0.9, 2.5])
    x0_vals = np.array([0.0, 4.0, 8.0])
    P = profile_posterior(model, z[0], bounds, "a", a_vals, x0_vals)
    assert P.shape == (4, 3)
    assert np.all(np.isneginf(P[0]))  # a <= 0 is outside the half-line prior (Eq. (14))
    for i in range(1, 4):
        for j in range(3):

            def f(xs):
                return -log_posterior(model, np.concatenate([[a_vals[i], x0_vals[j]], xs]), z[0])

            ref = minimize(f, np.zeros(4), method="BFGS", options={"gtol": 1e-10})
            assert np.isclose(P[i, j], -ref.fun, rtol=1e-9, atol=1e-9)
    # a ridge of variable height: the profile keeps rising towards large a (Fig. 4)
    assert P[3].max() > P[2].max() > P[1].max()


def test_profile_posterior_nonquadratic_and_fixed_parameters():
    model, x, z = design("sep_mult", [0.9], [8.0], T=8, K=1, seed=2)
    P = profile_posterior(model, z[0], model.prior_bounds([0.9]), "a", [0.5, 1.0], [6.0, 8.0])
    assert np.all(np.isfinite(P))
    i, j = 1, 1

    def f(xs):
        return -log_posterior(model, np.concatenate([[1.0, 8.0], xs]), z[0])

    ref = minimize(f, 8.0 + np.arange(1, 9) * 1.0, method="BFGS", options={"gtol": 1e-9})
    assert P[i, j] >= -ref.fun - 1e-7
    model2, x2, z2 = design("sep", [0.9, 0.9], [8.0], T=6, K=1, seed=3)
    with pytest.raises(ValueError, match="omega_fixed"):
        profile_posterior(model2, z2[0], model2.prior_bounds([0.9, 0.9]), "a", [0.5], [8.0])
    P2 = profile_posterior(
        model2,
        z2[0],
        model2.prior_bounds([0.9, 0.9]),
        "a",
        [0.5, 1.2],
        [8.0],
        omega_fixed={"b": 0.9},
    )
    assert np.isfinite(P2[0, 0]) and np.isneginf(P2[1, 0])
