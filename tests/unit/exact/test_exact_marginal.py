"""Exact marginal posteriors (issue 11): likelihood vs statsmodels and brute force, marginal
MAP vs a dense grid, Definition 3 and the improper-posterior detection."""

from __future__ import annotations

import numpy as np
import pytest
import ssmobs.exact.boundaries as boundaries
import ssmobs.exact.marginal as em
import ssmobs.exact.omega_grid as omega_grid
from scipy import integrate
from scipy.special import ndtr
from ssmobs.config.scenario import Scenario
from ssmobs.design.trajectories import make_trajectories
from ssmobs.exact.boundaries import boundary_slopes, improper
from ssmobs.exact.kalman_filter import kalman_marginal
from ssmobs.exact.marginal import exact_marginal
from ssmobs.exact.omega_grid import log_posterior_omega
from ssmobs.exact.settings import ExactSettings
from ssmobs.exact.state_mixtures import mixture_mode_quantiles
from ssmobs.models import MODELS, get_model

pytestmark = pytest.mark.unit

LINEAR = {
    "same": ([0.9], 8.0),
    "sep": ([0.9, 0.8], 8.0),
    "sep_d2_p1": ([0.9, 0.8, 0.7], 8.0),
    "sep_d1_p2": ([0.6, 0.5, 0.9, 0.8], [8.0, 8.0]),
    "sep_ranwalk": ([0.9], 8.0),
}


def _traj(slug, T, K, seed=0, omega=None):
    model = get_model(slug)
    om, x0 = LINEAR[slug]
    om = om if omega is None else omega
    sc = Scenario.from_config(
        {
            "name": slug,
            "model": slug,
            "x0": x0,
            "T": T,
            "K": K,
            "omega": dict(zip(model.param_names, om)),
        }
    )
    return make_trajectories(
        sc, np.random.default_rng(seed).standard_normal((sc.disturbance_dim, K))
    )


def test_linearity_flags():
    assert {s for s, m in MODELS.items() if m.linear_in_states} == set(LINEAR)
    assert not get_model("sep_mult").linear_in_states
    with pytest.raises(ValueError, match="not linear"):
        kalman_marginal(get_model("sep_mult"), np.array([0.5]), np.zeros((3, 1)))


def _statsmodels_loglike(model, omega, z):
    """statsmodels' exact diffuse log likelihood with the state alpha_1 = x0 (first
    observation missing), which equals log ∫ p(z | Omega, x0) dx0 up to a constant."""
    from statsmodels.tsa.statespace.mlemodel import MLEModel

    F, Q, H, R = model.state_space_matrices(np.asarray(omega, float))
    p = model.state_dim
    endog = np.vstack([np.full((1, z.shape[1]), np.nan), z])
    mod = MLEModel(endog, k_states=p, initialization="diffuse")
    mod.ssm["design"] = H
    mod.ssm["obs_cov"] = np.diag(R)
    mod.ssm["transition"] = F
    mod.ssm["selection"] = np.eye(p)
    mod.ssm["state_cov"] = np.diag(Q)
    return mod.ssm.loglike()


@pytest.mark.parametrize("slug", sorted(LINEAR))
def test_log_marginal_likelihood_matches_statsmodels(slug):
    pytest.importorskip("statsmodels")
    model = get_model(slug)
    traj = _traj(slug, T=12, K=2, seed=3)
    om = np.array(LINEAR[slug][0])
    omegas = [om, 0.9 * om, 0.6 * om, 0.3 * om]
    for z in traj.z:
        ours = np.array([-0.5 * kalman_marginal(model, o, z).neg2_loglik for o in omegas])
        ref = np.array([_statsmodels_loglike(model, o, z) for o in omegas])
        diff = ours - ref
        # the same function of Omega: only an Omega-independent constant apart
        np.testing.assert_allclose(diff, diff[0], atol=1e-8)
        # and that constant is (p/2) log(2 pi): statsmodels leaves out the flat prior's
        np.testing.assert_allclose(diff[0], 0.5 * model.state_dim * np.log(2 * np.pi), atol=1e-8)


def _brute_force_neg2(model, omega, z):
    """-2 log ∫ p(z | Omega, x0) dx0 by quadrature over x0 (z | x0 is Gaussian)."""
    F, Q, H, R = (a for a in model.state_space_matrices(np.asarray(omega, float)))
    T, d = z.shape
    p = model.state_dim
    # z = A x0 + B e with e the stacked disturbances: mean A x0, covariance C
    Fp = [np.linalg.matrix_power(F, t) for t in range(T + 1)]
    A = np.vstack([H @ Fp[t] for t in range(1, T + 1)])
    C = np.zeros((T * d, T * d))
    for s in range(1, T + 1):
        for t in range(1, T + 1):
            cov_st = sum(Fp[s - u] @ np.diag(Q) @ Fp[t - u].T for u in range(1, min(s, t) + 1))
            C[(s - 1) * d : s * d, (t - 1) * d : t * d] = H @ cov_st @ H.T
    C += np.kron(np.eye(T), np.diag(R))
    zf = z.reshape(-1)

    Ci = np.linalg.inv(C)
    _, logdet_C = np.linalg.slogdet(C)
    log_norm = -0.5 * (zf.size * np.log(2 * np.pi) + logdet_C)

    # integrate over x0 = centre + L v, v on [-12, 12]^p (L: the x0 scale from A and C) by
    # the trapezoidal rule on a grid of step 0.05 (its error for a smooth integrand that
    # vanishes at the ends is far below the tolerance), all points at once
    centre = np.linalg.solve(A.T @ Ci @ A, A.T @ Ci @ zf)
    L = np.linalg.cholesky(np.linalg.inv(A.T @ Ci @ A))
    v1 = np.linspace(-12.0, 12.0, 481)
    grid = np.stack(np.meshgrid(*([v1] * p), indexing="ij"), axis=-1).reshape(-1, p)
    resid = zf - (centre + grid @ L.T) @ A.T
    dens = np.exp(log_norm - 0.5 * np.einsum("ni,ij,nj->n", resid, Ci, resid))
    val = integrate.trapezoid(dens.reshape((v1.size,) * p), v1, axis=0)
    if p == 2:
        val = integrate.trapezoid(val, v1)
    return -2 * np.log(float(val) * np.linalg.det(L))


@pytest.mark.parametrize("slug", sorted(LINEAR))
def test_log_marginal_likelihood_matches_brute_force(slug):
    """T = 1..3 (from T = 2 for p = 2: one scalar observation cannot pin down two x0's)."""
    model = get_model(slug)
    om = np.array(LINEAR[slug][0])
    for T in range(model.state_dim, 4):
        traj = _traj(slug, T=T, K=1, seed=5)
        for o in (om, 0.7 * om):
            ours = kalman_marginal(model, o, traj.z[0]).neg2_loglik
            ref = _brute_force_neg2(model, o, traj.z[0])
            assert ours == pytest.approx(ref, abs=1e-6)


def test_smoothed_states_match_dense_gaussian_posterior():
    """Smoother means/variances equal those of the dense Gaussian posterior of x_0..x_T."""
    model = get_model("sep_d1_p2")
    traj = _traj("sep_d1_p2", T=4, K=1, seed=2)
    om = np.array(LINEAR["sep_d1_p2"][0])
    km = kalman_marginal(model, om, traj.z[0], smooth=True)
    # dense precision from the quadratic form of -2 log p(z, x | Omega)
    from ssmobs.models.log_posterior import neg2_log_posterior

    T, p = 4, 2
    theta = np.concatenate([om, np.zeros(p * (T + 1))])
    _, g, H = neg2_log_posterior(model, theta, traj.z[0], order=2)
    m = model.n_params
    P = H[m:, m:] / 2
    mean = np.linalg.solve(P, -g[m:] / 2)
    cov = np.linalg.inv(P)
    np.testing.assert_allclose(km.mean.reshape(-1), mean, rtol=1e-8, atol=1e-8)
    np.testing.assert_allclose(km.var.reshape(-1), np.diag(cov), rtol=1e-8)


def test_vectorised_over_omega_and_trajectories():
    model = get_model("sep")
    traj = _traj("sep", T=10, K=3)
    grid = np.stack(
        np.meshgrid(np.linspace(0.5, 0.95, 4), np.linspace(0.5, 0.95, 5), indexing="ij"), -1
    ).reshape(-1, 2)
    batch = kalman_marginal(model, grid[None], traj.z[:, None]).neg2_loglik
    assert batch.shape == (3, 20)
    one = [kalman_marginal(model, grid[i], traj.z[k]).neg2_loglik for k, i in [(2, 7), (0, 19)]]
    np.testing.assert_allclose([batch[2, 7], batch[0, 19]], one, rtol=1e-12)


def test_marginal_map_and_quantiles_match_dense_grid_same():
    """Exact marginal MAP and quantiles of a (Same) against a dense 1-D grid."""
    model = get_model("same")
    traj = _traj("same", T=20, K=3, seed=11)
    bounds = model.prior_bounds(traj.omega, "restricted")
    res = exact_marginal(model, traj.z, bounds)
    assert list(res.maxima) == ["unique"] * 3
    a = np.linspace(0.3, 0.999999, 400_001)
    for k in range(3):
        lp = log_posterior_omega(model, a[:, None], traj.z[k], bounds)
        dens = np.exp(lp - lp.max())
        cdf = np.concatenate([[0], np.cumsum((dens[1:] + dens[:-1]) / 2)])
        cdf /= cdf[-1]
        assert res.theta_map[k, 0] == pytest.approx(a[np.argmax(lp)], abs=2e-5)
        assert res.theta_q5[k, 0] == pytest.approx(np.interp(0.05, cdf, a), abs=2e-5)
        assert res.theta_q95[k, 0] == pytest.approx(np.interp(0.95, cdf, a), abs=2e-5)


def test_marginal_map_matches_dense_grid_sep_two_parameters():
    """Marginals of (a, b) of Sep against a dense 2-D grid for one trajectory."""
    model = get_model("sep")
    traj = _traj("sep", T=75, K=1, seed=4, omega=[0.9, 0.9])
    bounds = model.prior_bounds(traj.omega, "restricted")
    res = exact_marginal(model, traj.z, bounds)
    sd = res.laplace_sd[0]
    mode = res.joint_mode[0]
    axes = [
        np.linspace(max(mode[j] - 8 * sd[j], 1e-3), min(mode[j] + 8 * sd[j], 1 - 1e-9), 801)
        for j in range(2)
    ]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), -1)
    lp = log_posterior_omega(model, grid, traj.z[0], bounds)
    dens = np.exp(lp - lp.max())
    for j in range(2):
        marg = dens.sum(axis=1 - j)
        assert res.theta_map[0, j] == pytest.approx(axes[j][np.argmax(marg)], abs=5e-4)
        cdf = np.cumsum(marg) / marg.sum()
        assert res.theta_q5[0, j] == pytest.approx(np.interp(0.05, cdf, axes[j]), abs=2e-3)
        assert res.theta_q95[0, j] == pytest.approx(np.interp(0.95, cdf, axes[j]), abs=2e-3)


def test_state_quantiles_match_monte_carlo_over_omega():
    """The state mixtures against sampling: Omega from the dense-grid marginal, then x_0."""
    model = get_model("same")
    traj = _traj("same", T=20, K=1, seed=7)
    bounds = model.prior_bounds(traj.omega, "restricted")
    res = exact_marginal(model, traj.z, bounds)
    a = np.linspace(0.5, 0.999, 20_000)
    lp = log_posterior_omega(model, a[:, None], traj.z[0], bounds)
    w = np.exp(lp - lp.max())
    w /= w.sum()
    rng = np.random.default_rng(0)
    draws_a = rng.choice(a, size=400_000, p=w)
    km = kalman_marginal(model, draws_a[:, None], traj.z[0], smooth=True)
    x0 = km.mean[:, 0, 0] + np.sqrt(km.var[:, 0, 0]) * rng.standard_normal(draws_a.size)
    j = model.n_params  # x0 is the first state
    assert res.theta_q5[0, j] == pytest.approx(np.quantile(x0, 0.05), abs=0.02)
    assert res.theta_q95[0, j] == pytest.approx(np.quantile(x0, 0.95), abs=0.02)


def test_state_quantiles_do_not_move_when_the_state_grid_is_refined(monkeypatch):
    """(Sep, d=2, p=1), only a restricted, T = 50: the fine box widens along a long tail
    toward a = b = 0; a state grid spread over that whole box put its nodes about 3 sd
    apart and moved x0's quantiles by up to 0.15 against a refined grid (and Stan).  On
    the part of the box that holds all but 1e-6 of the mass the mixture has converged: 31
    nodes per axis, a box of ± 9 sd and a tail mass of 1e-9 move no quantile of x0 by more
    than 0.02."""
    model = get_model("sep_d2_p1")
    omega = np.array([0.9, 0.9, 0.9])
    bounds = model.prior_bounds(
        omega, {"a": "restricted", "b": "unrestricted", "c": "unrestricted"}
    )
    rng = np.random.default_rng(7)
    eta, eps = rng.standard_normal((12, 50, 1)), rng.standard_normal((12, 50, 2))
    _, z = model.simulate(omega, np.array([8.0]), eta, eps)
    z = z[[3, 7, 11]]  # before the fix: x0's quantiles 0.08-0.15 off on these
    boxes = []
    state_box = em.state_box

    def spy(mass, lo_box, hi_box, settings):
        boxes.append(hi_box - lo_box)
        return state_box(mass, lo_box, hi_box, settings)

    monkeypatch.setattr(em, "state_box", spy)
    default = exact_marginal(model, z, bounds)
    # the premise: every fine box widened well beyond mode ± box_sd sd in some axis
    widths = boxes[0] / default.laplace_sd
    assert np.all(widths.max(1) > 2 * 2 * ExactSettings().box_sd), widths
    fine = ExactSettings(
        state_nodes=(41, 21, 31, 7), state_thin=(10, 3, 1, 2), box_sd=9.0, state_tail_mass=1e-9
    )
    refined = exact_marginal(model, z, bounds, fine)
    j = default.theta_names.index("x0")
    assert list(default.maxima) == ["unique"] * 3
    for q in ("theta_q5", "theta_q95"):
        assert np.abs(getattr(default, q)[:, j] - getattr(refined, q)[:, j]).max() < 0.02, q


def test_mixture_quantiles_converge_with_a_light_very_wide_component():
    """A component of weight 1e-5 and sd 4e5 (a node at a box corner) makes the bracket
    ~1e7 wide; 16 fixed steps left the 5 % quantile at 186 > the 95 % quantile.  Every
    element (trajectory, state) of a batch converges on its own mixture."""
    rng = np.random.default_rng(3)
    K, G, S = 2, 4, 3
    w = rng.uniform(0.1, 1, (K, G, S))
    w[:, -1, :] = 1e-5  # one light, very wide component everywhere
    w /= w.sum(1, keepdims=True)
    mean = rng.normal(8, 1, (K, G, S))
    sd = rng.uniform(0.5, 2, (K, G, S))
    sd[:, -1, :] = 4e5
    order = np.argsort(-w, axis=1)  # heaviest first, as the caller sorts them
    w, mean, sd = (np.take_along_axis(a, order, 1) for a in (w, mean, sd))
    _, q = mixture_mode_quantiles(w, mean, sd, ExactSettings())
    assert q.shape == (K, S, 2)
    for k in range(K):
        for t in range(S):
            cdf = (w[k, :, t] * ndtr((q[k, t][:, None] - mean[k, :, t]) / sd[k, :, t])).sum(1)
            assert cdf == pytest.approx([0.05, 0.95], abs=1e-9), (k, t)


def test_same_is_improper_at_zero_like_minus_two_log_a():
    """log p(a | z) rises like -2 log a as a -> 0+ (flat prior on x0): improper there;
    the marginal MAP is the interior maximum."""
    model = get_model("same")
    traj = _traj("same", T=20, K=4, seed=1)
    bounds = model.prior_bounds(traj.omega, "restricted")
    a = np.array([1e-3, 1e-4, 1e-5, 1e-6])[:, None]
    for z in traj.z:
        lp = log_posterior_omega(model, a, z, bounds)
        slopes = np.diff(lp) / np.diff(np.log(a[:, 0]))
        np.testing.assert_allclose(slopes, -2.0, atol=0.02)
    lower, upper = boundary_slopes(model, traj.z, bounds, np.full((4, 1), 0.9))
    np.testing.assert_allclose(lower, -2.0, atol=0.02)
    assert improper(lower, finite=True).all()
    assert not improper(upper, finite=True).any()  # a -> 1: the density vanishes
    res = exact_marginal(model, traj.z, bounds)
    frame = res.to_frame(model)
    assert frame["improper_lower_a"].all() and not frame["improper_upper_a"].any()
    assert (frame["maxima"] == "unique").all() and frame["converged"].all()
    assert ((frame["a_map"] > 0.7) & (frame["a_map"] < 1)).all()
    assert (frame["spike_ratio"] < 1e-10).all()


def test_ranwalk_improper_at_zero_and_classified():
    """ranWalk: p(a | z) ~ 1/a at 0+ (improper); short series have no interior maximum
    for some trajectories (Definition 3: 'none') and no estimates there."""
    model = get_model("sep_ranwalk")
    traj = _traj("sep_ranwalk", T=4, K=40, seed=0)
    bounds = model.prior_bounds(traj.omega, "half_line")
    res = exact_marginal(model, traj.z, bounds)
    frame = res.to_frame(model)
    assert frame["improper_lower_a"].all()
    np.testing.assert_allclose(frame["slope_lower_a"], -1.0, atol=0.05)
    none = frame["maxima"] == "none"
    assert none.any()
    assert frame.loc[none, "a_map"].isna().all() and not frame.loc[none, "converged"].any()
    # where a unique maximum is reported it is a local maximum of log p(a | z)
    uniq = frame["maxima"] == "unique"
    mode = frame.loc[uniq, "mode_a"].to_numpy()
    z = traj.z[uniq.to_numpy()]
    for f in (0.98, 1.02):
        assert (
            log_posterior_omega(model, (mode * f)[:, None, None], z[:, None], bounds)[:, 0]
            < log_posterior_omega(model, mode[:, None, None], z[:, None], bounds)[:, 0]
        ).all()


def test_sep_d1_p2_is_not_uniquely_identified():
    """(Sep, d=1, p=2): swapping (a, c, x_1) with (b, d, x_2) leaves the likelihood
    unchanged, so no trajectory has a unique interior maximum of p(a, b, c, d | z)."""
    model = get_model("sep_d1_p2")
    traj = _traj("sep_d1_p2", T=20, K=3, seed=0)
    z = traj.z[0]
    om = np.array([0.6, 0.5, 0.9, 0.8])
    swapped = om[[1, 0, 3, 2]]
    assert kalman_marginal(model, om, z).neg2_loglik == pytest.approx(
        kalman_marginal(model, swapped, z).neg2_loglik, rel=1e-12
    )
    bounds = model.prior_bounds(traj.omega, "restricted")
    settings = ExactSettings(coarse_nodes=(400, 48, 16, 7), state_nodes=(41, 21, 11, 4))
    res = exact_marginal(model, traj.z, bounds, settings)
    assert not (res.maxima == "unique").any()


def test_several_maxima_detected_on_a_bimodal_posterior(monkeypatch):
    """Definition 3 'several': a posterior with two separated interior maxima."""
    model = get_model("same")
    traj = _traj("same", T=20, K=2, seed=0)
    bounds = model.prior_bounds(traj.omega, "restricted")

    def two_bumps(model_, omega, z, bounds_):
        a = np.asarray(omega)[..., 0]
        val = np.logaddexp(-0.5 * ((a - 0.3) / 0.02) ** 2, -0.5 * ((a - 0.8) / 0.03) ** 2)
        ok = (a > 0) & (a < 1)
        return np.where(
            ok, np.broadcast_to(val, np.broadcast_shapes(val.shape, np.shape(z)[:-2])), -np.inf
        )

    # the grid's density and the boundary slopes both call it
    monkeypatch.setattr(omega_grid, "log_posterior_omega", two_bumps)
    monkeypatch.setattr(boundaries, "log_posterior_omega", two_bumps)
    res = em.exact_marginal(model, traj.z, bounds)
    assert list(res.maxima) == ["several", "several"]
    assert not res.to_frame(model)["converged"].any()


def test_summary_has_the_stan_stage_keys():
    import pandas as pd
    from ssmobs.nuts.stan_metrics import stan_summary
    from ssmobs.stages.exact import exact_summary

    model = get_model("same")
    traj = _traj("same", T=20, K=20, seed=2)
    bounds = model.prior_bounds(traj.omega, "restricted")
    frame = exact_marginal(model, traj.z, bounds).to_frame(model)
    info = exact_summary(frame, model, traj.omega, traj.x0, traj.x)
    assert set(stan_summary(frame, model, traj.omega, traj.x0, traj.x)) <= set(info)
    assert info["n_exact"] == info["n_unique"] == 20
    assert 0.5 < info["a_cover90"] <= 1 and abs(info["a_bias"]) < 0.05
    assert isinstance(frame, pd.DataFrame) and frame["k"].tolist() == list(range(20))
