"""Joint MAP estimates per design trajectory and their numerical checks (Sec. III.B).

For every design observation trajectory z~(k) we minimise -2 pi(Theta | z~(k)) over
Theta = (Omega, x_0, x_1..x_T) and check the maximum found; this module is the driver, its
result (one row per k) and the scenario summary over K^max (Table II).  Its parts:

- :mod:`ssmobs.joint_map.settings`: thresholds and tuning (:class:`JointMapSettings`);
- :mod:`ssmobs.joint_map.barrier`: the primal log-barrier Newton solver and its start mu_0;
- :mod:`ssmobs.joint_map.checks`: the checks of a found maximum (statuses, eigenvalue
  ratio, ridge re-check) and the local variances.

Trajectories are optimised in contiguous batches of k, each vectorised over k.

Start (Sec. III.B): (Omega_true, x0_true, model.initial_states(Omega_true, z~(k))), i.e. the
observations themselves when d == p as in the paper (see the models for d != p).
``start_states = "sign_of_x0"`` instead starts the states at
``model.sign_consistent_states`` (for (Sep, Multiplicative): |z_t| / sqrt(a) with the sign
of x_0), an alternative shown beside the paper's start.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
import pandas as pd

from ..estimator_moments import moment_entries, stat_key
from ..models.base import StateSpaceModel
from .barrier import LogBarrier, initial_mu_values, minimize_barrier
from .checks import STATUSES, check_maxima
from .problem import JointMapProblem
from .settings import JointMapSettings


@dataclass
class JointMapResult:
    """Per-trajectory joint-MAP results (index k = column of the design matrix, from 0).

    Attributes
    ----------
    theta_hat : (K, n) Theta_hat = (Omega, x_0, x_1..x_T).
    neg2_log_post : (K,) -2 pi(Theta_hat | z~(k)) (up to the model's additive constant).
    local_variance : (K, n) LVar_j = 2 (H_{-2 pi}^{-1})_jj (NaN where H is not PD).
    eig_ratio : (K,) lambda_min / lambda_max of H_{-2 pi}(Theta_hat).
    grad_max : (K,) max_j |d(-2 pi)/dTheta_j| at Theta_hat.
    iterations : (K,) Newton iterations (the ridge re-optimisation not included).
    status : (K,) one of :data:`STATUSES`.
    reason : (K,) short explanation ("" for ok).
    theta_names : names of the components of Theta.
    mu_start : (K,) the barrier start mu_0 of each trajectory.
    ridge_value_change : (K,) |change of -2 pi| in the ridge re-check (NaN where not run).
    """

    theta_hat: np.ndarray
    neg2_log_post: np.ndarray
    local_variance: np.ndarray
    eig_ratio: np.ndarray
    grad_max: np.ndarray
    iterations: np.ndarray
    status: np.ndarray
    reason: np.ndarray
    theta_names: list[str] = field(default_factory=list)
    mu_start: np.ndarray | None = None
    ridge_value_change: np.ndarray | None = None

    @classmethod
    def unfilled(cls, K: int, theta_names: list[str], status: str, reason: str) -> JointMapResult:
        """A result for K trajectories of ``len(theta_names)`` components, every value NaN
        (iterations 0), every status and reason the given ones, to be filled row by row."""
        n = len(theta_names)
        return cls(
            theta_hat=np.full((K, n), np.nan),
            neg2_log_post=np.full(K, np.nan),
            local_variance=np.full((K, n), np.nan),
            eig_ratio=np.full(K, np.nan),
            grad_max=np.full(K, np.nan),
            iterations=np.zeros(K, dtype=np.int64),
            status=np.full(K, status, dtype=object),
            reason=np.full(K, reason, dtype=object),
            theta_names=list(theta_names),
        )

    @property
    def ok(self) -> np.ndarray:
        """(K,) True for k in K^max."""
        return self.status == "ok"

    def to_frame(self, model: StateSpaceModel, T: int) -> pd.DataFrame:
        """One row per k: k, status, reason, neg2_log_post, eig_ratio, grad_max, iterations,
        and for every component c of Omega and x_0 its estimate ``c`` and ``lvar_c``."""
        names = model.theta_names(T)
        head = model.n_params + model.state_dim
        frame = pd.DataFrame(
            {
                "k": np.arange(self.theta_hat.shape[0], dtype=np.int64),
                "status": pd.Series(self.status, dtype=object).astype(str),
                "reason": pd.Series(self.reason, dtype=object).astype(str),
                "neg2_log_post": self.neg2_log_post.astype(float),
                "eig_ratio": self.eig_ratio.astype(float),
                "grad_max": self.grad_max.astype(float),
                "iterations": self.iterations.astype(np.int64),
            }
        )
        K = self.theta_hat.shape[0]
        frame["mu0"] = np.full(K, np.nan) if self.mu_start is None else self.mu_start.astype(float)
        frame["ridge_value_change"] = (
            np.full(K, np.nan)
            if self.ridge_value_change is None
            else self.ridge_value_change.astype(float)
        )
        for j, name in enumerate(names[:head]):
            frame[name] = self.theta_hat[:, j]
        for j, name in enumerate(names[:head]):
            frame[f"lvar_{name}"] = self.local_variance[:, j]
        return frame


class ProgressLike(Protocol):
    """What the solver reports finished trajectories to (a counter with ``update``)."""

    def update(self, n: int = 1) -> None: ...


def _chunks(K: int, n: int, settings: JointMapSettings) -> list[slice]:
    """Contiguous batches of k; memory per trajectory is O(n (lanczos_steps + (m + 2p)^2))."""
    size = settings.chunk_size or int(np.clip(2e5 / n, 64, 2048))
    return [slice(s, min(s + size, K)) for s in range(0, K, size)]


def simulated_states(
    model: StateSpaceModel, omega: np.ndarray, x0: np.ndarray, K: int, T: int
) -> np.ndarray:
    """(K, T, p) the model's own noise-free path from x_0: ``simulate`` with eta = eps = 0
    (a start of the states on the branch the dynamics choose, whatever z says)."""
    eta = np.zeros((K, T, model.state_dim))
    eps = np.zeros((K, T, model.obs_dim))
    with np.errstate(all="ignore"):
        x, _ = model.simulate(np.asarray(omega, float), np.asarray(x0, float), eta, eps)
    return np.asarray(x, dtype=float)


def initial_theta(
    model: StateSpaceModel,
    z: np.ndarray,
    omega_true: np.ndarray,
    x0_true: np.ndarray,
    start_states: str = "observations",
) -> np.ndarray:
    """Start of Sec. III.B: (Omega_true, x0_true, initial_states(Omega_true, z)) for every k.

    ``start_states="sign_of_x0"``: the states start at
    ``model.sign_consistent_states(Omega_true, x0_true, z)`` instead; ``"simulate"``: at
    :func:`simulated_states` (the model's own path from x0_true, the data unused).
    """
    K, T, _ = z.shape
    if start_states == "sign_of_x0":
        x = np.asarray(model.sign_consistent_states(omega_true, x0_true, z), dtype=float)
    elif start_states == "simulate":
        x = simulated_states(model, omega_true, x0_true, K, T)
    else:
        x = np.asarray(model.initial_states(omega_true, z), dtype=float)
    if x.shape != (K, T, model.state_dim):
        raise ValueError(
            f"initial_states of model '{model.slug}' returned shape {x.shape}, "
            f"expected {(K, T, model.state_dim)}"
        )
    return np.concatenate(
        [
            np.broadcast_to(omega_true, (K, model.n_params)),
            np.broadcast_to(x0_true, (K, model.state_dim)),
            x.reshape(K, -1),
        ],
        axis=1,
    )


def joint_map(
    problem: JointMapProblem,
    progress: ProgressLike | None = None,
    theta_start: np.ndarray | None = None,
) -> JointMapResult:
    """Joint MAP estimate and numerical checks for every design trajectory (Sec. III.B).

    Parameters
    ----------
    problem : the model, the (K, T, d) design observations z~(k), the support of the flat
        prior on Omega (from ``model.prior_bounds``), the true values (the start of every
        optimisation) and the settings (:class:`JointMapProblem`).
    progress : optional object with ``update(n)`` (e.g. :class:`ssmobs.log.Progress`),
        called after each batch with the number of trajectories finished.
    theta_start : optional (K, |Theta|) start of every trajectory's optimisation instead of
        :func:`initial_theta` (the multi-start's images of maxima,
        :mod:`ssmobs.joint_map.multi_start`);
        each row's Omega must lie strictly inside the support.

    Returns
    -------
    JointMapResult with per-k arrays; ``status == "ok"`` marks K^max.  A numerical failure
    of one trajectory never raises: it is recorded as ``failed`` with a reason.
    """
    model, bounds, settings = problem.model, problem.bounds, problem.settings
    z = np.asarray(problem.z, dtype=float)
    if z.ndim != 3 or z.shape[2] != model.obs_dim:
        raise ValueError(
            f"z must have shape (K, T, {model.obs_dim}) for model '{model.slug}', got {z.shape}"
        )
    K, T, _ = z.shape
    omega = np.asarray(problem.omega_true, dtype=float)
    x0 = np.atleast_1d(np.asarray(problem.x0_true, dtype=float))
    if omega.shape != (model.n_params,):
        raise ValueError(
            f"omega_true must have {model.n_params} value(s) in the order "
            f"{list(model.param_names)}, got {omega.tolist()}"
        )
    if x0.shape != (model.state_dim,):
        raise ValueError(f"x0_true must have {model.state_dim} component(s), got {x0.tolist()}")
    barrier = LogBarrier(model, bounds)
    if not np.isfinite(barrier.value(omega[None, :]))[0]:
        raise ValueError(
            f"start Omega={omega.tolist()} is not strictly inside the prior support "
            f"({bounds.lower.tolist()}, {bounds.upper.tolist()}) and the model "
            f"constraints"
        )
    n = model.n_theta(T)
    out = JointMapResult.unfilled(K, model.theta_names(T), "failed", "")
    out.mu_start = np.full(K, np.nan)
    out.ridge_value_change = np.full(K, np.nan)
    for sl in _chunks(K, n, settings):
        zc = z[sl]
        if theta_start is None:
            theta0 = initial_theta(model, zc, omega, x0, settings.start_states)
        else:
            theta0 = np.array(theta_start[sl], dtype=float)
        mu_start = initial_mu_values(model, zc, theta0, barrier, settings)
        theta, iters, mu, stop = minimize_barrier(model, zc, theta0, barrier, settings, mu_start)
        res = check_maxima(model, zc, theta, mu, stop, barrier, settings)
        assert out.mu_start is not None  # set above
        out.mu_start[sl] = mu_start
        out.theta_hat[sl] = theta
        out.iterations[sl] = iters
        for key, val in res.items():
            getattr(out, key)[sl] = val
        if progress is not None:
            progress.update(sl.stop - sl.start)
    return out


def component_names(model: StateSpaceModel) -> list[str]:
    """Names of the components of Omega and x_0 (the columns of :meth:`JointMapResult.to_frame`)."""
    return model.theta_names(0)


def joint_map_summary(
    frame: pd.DataFrame, model: StateSpaceModel, omega_true: np.ndarray, x0_true: np.ndarray
) -> dict[str, Any]:
    """Scenario summary of the joint MAP estimator over K^max (Sec. III.B, Table II).

    Keys: ``K``, ``K_max`` (= |K^max|), ``ratio`` (= |K^max| / K), ``components``, the count
    per status ``n_<status>``, and per component c of Omega and x_0 (``<component>_<stat>``,
    as the Stan stage's :func:`ssmobs.nuts.stan_metrics.stan_summary`): ``c_mean``, ``c_var``
    (ddof = 1, as in Table II), ``c_mse`` (mean squared error about the true value, divided
    by |K^max|), ``c_bias`` and ``c_lvar_mean`` (mean local variance).  Values that are not
    defined (|K^max| = 0, or 1 for the variance) are NaN.
    """
    names = component_names(model)
    truth = np.concatenate(
        [
            np.atleast_1d(np.asarray(omega_true, dtype=float)),
            np.atleast_1d(np.asarray(x0_true, dtype=float)),
        ]
    )
    if truth.size != len(names):
        raise ValueError(f"true values {truth.tolist()} do not match components {names}")
    missing = [
        c for c in ["status", *names, *[f"lvar_{c}" for c in names]] if c not in frame.columns
    ]
    if missing:
        raise ValueError(f"joint-MAP frame lacks columns {missing}")
    ok = (frame["status"] == "ok").to_numpy()
    K = int(len(frame))
    k_max = int(ok.sum())
    out: dict[str, Any] = {
        "K": K,
        "K_max": k_max,
        "ratio": k_max / K if K else float("nan"),
        "components": names,
    }
    counts = frame["status"].value_counts()
    for st in STATUSES:
        out[f"n_{st}"] = int(counts.get(st, 0))
    for c, true in zip(names, truth):
        est = frame.loc[ok, c].to_numpy(dtype=float)
        lv = frame.loc[ok, f"lvar_{c}"].to_numpy(dtype=float)
        out.update(moment_entries(c, est, true))
        out[stat_key(c, "lvar_mean")] = float(lv.mean()) if k_max else float("nan")
    return out


def joint_map_of(
    problem: JointMapProblem, progress: ProgressLike | None = None
) -> tuple[JointMapResult, pd.DataFrame, dict[str, Any]]:
    """Joint MAP of every trajectory from the paper's start: the result, its per-k table
    and its summary over K^max (:func:`joint_map_summary`)."""
    result = joint_map(problem, progress=progress)
    frame = result.to_frame(problem.model, problem.T)
    summary = joint_map_summary(frame, problem.model, problem.omega_true, problem.x0_true)
    return result, frame, summary
