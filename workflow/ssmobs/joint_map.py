"""Joint MAP estimates per design trajectory and their numerical checks (Sec. III.B).

For every design observation trajectory z~(k) we minimise -2 pi(Theta | z~(k)) over
Theta = (Omega, x_0, x_1..x_T) with a primal log-barrier method ([26, Sec. 19.6]):

    P_mu(Theta) = -2 pi(Theta | z) - mu * sum_i log s_i(Omega),

where the slacks s_i > 0 are the finite prior bounds (Omega_j - lower_j, upper_j - Omega_j)
and the model constraints c(Omega) > 0 (e.g. 1 - a^2 - b^2 for (Sep, d=1, p=2)).  For each
mu the barrier problem is solved by Newton's method with the analytic Hessian and an
Armijo backtracking line search whose first trial step is cut to a fraction
(``fraction_to_boundary``) of the distance to the prior box and which rejects any trial
point with a non-positive slack, so every iterate stays strictly feasible.  mu starts at
``max(mu0, mu0_per_step * T)`` and is multiplied by ``mu_factor`` each time the barrier
gradient falls below ``max(inner_tol_factor * mu, newton_tol)``, down to ``mu_min``; the
iteration stops at ``max |grad P| <= newton_tol`` with mu = mu_min.

The barrier start mu_0 (the paper gives none).  ``mu0_rule = "gradient_balance"`` (the
default) takes, per trajectory, the mu_0 at which the barrier and -2 pi pull equally hard
on Omega at the start Theta_0:

    mu_0 = || grad_Omega (-2 pi)(Theta_0) ||_2 / || grad_Omega B(Theta_0) ||_2,
    B = -sum log s_i,

i.e. the barrier term holds half of the Omega-gradient of P_mu at the start (floored at
``mu_min``; where there is no barrier the value does not matter).  A smaller mu_0 lets the
first Newton steps follow -2 pi alone, which in several models is unbounded below at the
edge of the support (in (Sep, d=p=1) it contains T log(1 - b^2), and x_t = z_t / b makes
the observation residuals vanish as b -> 1); a much larger one makes the first stages
ignore the data.  ``mu0_rule = "per_step"`` keeps the former rule mu_0 = max(mu0,
mu0_per_step * T) (mu_0 above about T bounds that singular term); the rule
``joint_map_mu0_sweep`` compares both over a range of mu_0.

All trajectories are optimised together: every Newton iteration evaluates the per-step
symbolic derivatives for the whole batch and solves the K Newton systems at once.  The
Hessian is an "arrow" matrix (block-tridiagonal in the states plus m dense rows/columns
for Omega), so each system is solved in O(T (p^3 + p^2 m + m^2) + m^3) by a block
Cholesky of the state part and an m x m Schur complement, vectorised over k with a loop
over t (:mod:`ssmobs.banded_linalg`).  Where the Hessian is not positive definite a
multiple of the identity is added (modified Newton, [26, Sec. 3.4]).  A trajectory stops
early once it has run off to infinity (``divergence_limit``) or onto the boundary
(slack < ``boundary_stop_tol``).

Numerical checks at the result Theta_hat (Sec. III.B), giving one status per k, checked in
this order (the first that applies wins):

``failed``
    value, gradient, Hessian or Theta_hat not finite (reason in ``reason``).
``boundary``
    the optimum lies on the boundary of the prior's support: a slack below
    ``boundary_tol``, or (for a converged run) a barrier multiplier mu / s_i above
    ``grad_tol`` (the barrier is what holds the point), or (for a run that did not
    converge) a slack below ``boundary_near_tol`` with -2 pi still decreasing towards that
    constraint faster than ``grad_tol``, or the iterates ran off to infinity
    (``|Theta|_inf`` above ``divergence_limit``; the supremum is approached at the edge of
    an unbounded support, as for a ridge of variable height).
``not-positive-definite``
    the Hessian of -2 pi is not positive definite: its block Cholesky factorisation fails
    or its smallest eigenvalue is not above ``pd_tol``.
``gradient``
    largest absolute gradient component of -2 pi not below ``grad_tol`` (1e-5 in the paper);
    typical for runs stopped by ``max_newton_iter`` while climbing a ridge.
``ridge``
    eigenvalue ratio lambda_min / lambda_max below ``eig_ratio_min`` (r_0 = 1e-5) and a new
    optimisation started at Theta_hat + h v_min (v_min the unit eigenvector of the smallest
    eigenvalue, h = ``ridge_shift``, halved until the start is inside the support) ends more
    than ``ridge_move_tol`` away (sup norm), or ends non-finite or diverged.  If it returns
    to Theta_hat the trajectory is ``ok`` (the reason column records the check).
``ok``
    all checks passed: k belongs to K^max.

Eigenvalues: lambda_max by Lanczos on H, lambda_min and v_min by Lanczos on H^{-1} (applied
through the factorisation), ``lanczos_steps`` steps with full reorthogonalisation;
``eigen_method="dense"`` uses LAPACK instead (O(n^3), for checks).

Local variances (Sec. II.B): LVar_j = -H_pi^{-1}(Theta_hat)_jj = 2 (H_{-2 pi}^{-1})_jj for
every component, by a selected inversion of the factorised arrow matrix, wherever the
Hessian is positive definite (NaN otherwise).

Start (Sec. III.B): (Omega_true, x0_true, model.initial_states(Omega_true, z~(k))), i.e. the
observations themselves when d == p as in the paper (see the models for d != p).
``start_states = "sign_of_x0"`` instead starts the states at
``model.sign_consistent_states`` (for (Sep, Multiplicative): |z_t| / sqrt(a) with the sign
of x_0), an alternative shown beside the paper's start.

The ridge re-check records both how far the re-optimised point moved (sup norm) and how
much -2 pi changed; ``ridge_test`` says which decides (see :class:`JointMapSettings`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
import pandas as pd

from .banded_linalg import ArrowFactor, arrow_extreme_eigenpairs
from .estimator_moments import moment_entries, stat_key
from .models.base import PriorBounds, StateSpaceModel
from .models.log_posterior import compile_model, neg2_log_posterior, neg2_log_posterior_blocks

#: the six statuses, in the order in which the checks assign them
STATUSES: tuple[str, ...] = (
    "ok",
    "not-positive-definite",
    "gradient",
    "ridge",
    "boundary",
    "failed",
)


# =========================================================================== settings
@dataclass(frozen=True)
class JointMapSettings:
    """Thresholds and tuning of the joint-MAP optimiser and its checks (Sec. III.B).

    The config's ``joint_map`` block (``workflow/schemas/config.schema.yaml``) sets the
    paper's thresholds and the choices a study varies (the start of the barrier, the ridge
    test); every key of it is a field (a test compares the two).

    Fixed fields, not in the config (code that calls :func:`joint_map` itself may set them):

    - ``start_states``: set per scenario instead (its ``joint_map_start``);
    - the solver's numerics, how the optimum and the Hessian's extreme eigenvalues are
      computed: ``newton_tol``, ``inner_tol_factor``, ``mu_factor``, ``mu_min``,
      ``fraction_to_boundary``, ``armijo_c1``, ``max_backtracks``, ``damping_init``,
      ``max_damping_tries``, ``eigen_method``, ``lanczos_steps``;
    - the thresholds of our checks that the paper does not name: ``pd_tol``,
      ``ridge_shift``, ``boundary_tol``, ``boundary_stop_tol``, ``boundary_near_tol``,
      ``divergence_limit``.

    A fixed value changes by an edit of this module, which moves the key of every result
    computed with it (:mod:`ssmobs.cache_keys` hashes the code a stage runs), so no cached
    result outlives the change.
    """

    #: gradient check: max |d(-2 pi)/dTheta_j| must be below this (paper: 1e-5)
    grad_tol: float = 1e-5
    #: eigenvalue check: lambda_min / lambda_max must be above this (paper: r_0 = 1e-5)
    eig_ratio_min: float = 1e-5
    #: Hessian check: lambda_min must be above this
    pd_tol: float = 0.0
    #: Newton iterations per trajectory (all barrier stages together)
    max_newton_iter: int = 200
    #: stop when max |grad P_mu| <= newton_tol at mu = mu_min (absolute, units of -2 pi)
    newton_tol: float = 1e-9
    #: inner stopping rule for mu > mu_min: max |grad P_mu| <= inner_tol_factor * mu
    inner_tol_factor: float = 1.0
    #: initial barrier parameter: mu_0 = max(mu0, mu0_per_step * T).  -2 pi has up to T
    #: log-singular terms per constraint (e.g. T log(1 - b^2) in (Sep, d=p=1), which go to
    #: -inf at b -> 1 with x_t = z_t / b), so the first barrier problem is bounded below
    #: only for mu_0 above about T; smaller values let the first Newton steps fall into
    #: that singular edge of the joint posterior instead of an interior local maximum.
    mu0: float = 1.0
    mu0_per_step: float = 2.0
    #: how mu_0 is chosen: "gradient_balance" (per trajectory: the barrier's Omega-gradient
    #: equals that of -2 pi at the start; module docstring) or "per_step" (the formula above)
    mu0_rule: str = "gradient_balance"
    #: start of the states: "observations" (the paper's x = z) or "sign_of_x0"
    #: (model.sign_consistent_states; only models that define it)
    start_states: str = "observations"
    #: mu <- mu * mu_factor after each barrier stage
    mu_factor: float = 0.01
    #: final barrier parameter ("near zero")
    mu_min: float = 1e-10
    #: a step goes at most this fraction of the way to a prior bound
    fraction_to_boundary: float = 0.995
    #: Armijo sufficient-decrease constant
    armijo_c1: float = 1e-4
    #: step halvings before the line search gives up
    max_backtracks: int = 50
    #: first diagonal shift (relative to 1 + max |H_jj|) when the Hessian is not PD
    damping_init: float = 1e-8
    #: shift multiplications by 10 before falling back to steepest descent
    max_damping_tries: int = 25
    #: length of the shift along the smallest-eigenvalue eigenvector for the ridge check
    ridge_shift: float = 0.1
    #: the ridge re-optimisation "moved" if it ends farther than this (sup norm) from Theta_hat
    ridge_move_tol: float = 1e-4
    #: ... or, with ridge_test = "value", if -2 pi there differs by more than
    #: ridge_value_tol * (1 + |-2 pi(Theta_hat)|)
    ridge_value_tol: float = 1e-8
    #: what decides a ridge after the re-optimisation: "location" (the point moved: catches
    #: ridges of constant height, where the value cannot change) or "value" (the paper's
    #: wording "leads to a different value")
    ridge_test: str = "location"
    #: a slack s_i(Omega_hat) below this means the optimum is on the boundary
    boundary_tol: float = 1e-6
    #: the iterations of a trajectory stop early once a slack falls below this
    boundary_stop_tol: float = 1e-6
    #: a run that did not converge and ends with a slack below this while -2 pi still
    #: decreases towards that constraint (gradient check would fail) is ``boundary``
    boundary_near_tol: float = 1e-4
    #: |Theta|_inf above this means the iterates run off to infinity (boundary at infinity)
    divergence_limit: float = 1e6
    #: extreme eigenvalues of the Hessian: "lanczos" (structured, O(n) per step) or "dense"
    eigen_method: str = "lanczos"
    #: Lanczos steps (exact spectrum when >= |Theta|)
    lanczos_steps: int = 24
    #: trajectories per vectorised batch (0: about 2e5 / |Theta|, between 64 and 2048)
    chunk_size: int = 0
    #: starts per trajectory (:mod:`ssmobs.multi_start`): 1 is the paper's start alone; n > 1
    #: adds n - 1 starts spread over the start box by a Halton sequence
    n_starts: int = 1
    #: two maxima that pass the checks are one if no component of Theta differs by more
    #: than this many local standard deviations sqrt(LVar_j) (:mod:`ssmobs.multi_start`)
    distinct_tol: float = 1e-2
    #: start box: a side of Omega's prior box without a finite bound, and both sides of
    #: x_0's, lie this many max(1, |true value|) from the true value
    start_box_span: float = 3.0

    def __post_init__(self) -> None:
        positive = (
            "grad_tol",
            "eig_ratio_min",
            "newton_tol",
            "inner_tol_factor",
            "mu0",
            "mu_min",
            "armijo_c1",
            "damping_init",
            "ridge_shift",
            "ridge_move_tol",
            "ridge_value_tol",
            "boundary_tol",
            "boundary_stop_tol",
            "boundary_near_tol",
            "divergence_limit",
            "distinct_tol",
            "start_box_span",
        )
        for name in positive:
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"joint-MAP setting {name}={value!r} must be a positive number")
        for name in (
            "max_newton_iter",
            "max_backtracks",
            "max_damping_tries",
            "lanczos_steps",
            "n_starts",
        ):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"joint-MAP setting {name}={getattr(self, name)!r} must be >= 1")
        if not 0 < self.mu_factor < 1:
            raise ValueError(f"joint-MAP setting mu_factor={self.mu_factor!r} must be in (0, 1)")
        if not 0 < self.fraction_to_boundary < 1:
            raise ValueError(
                f"joint-MAP setting fraction_to_boundary={self.fraction_to_boundary!r}"
                " must be in (0, 1)"
            )
        if self.mu_min > self.mu0:
            raise ValueError(
                f"joint-MAP setting mu_min={self.mu_min!r} must not exceed mu0={self.mu0!r}"
            )
        if self.mu0_per_step < 0:
            raise ValueError(f"joint-MAP setting mu0_per_step={self.mu0_per_step!r} must be >= 0")
        if self.boundary_stop_tol > self.boundary_tol:
            raise ValueError(
                f"joint-MAP setting boundary_stop_tol={self.boundary_stop_tol!r} "
                f"must not exceed boundary_tol={self.boundary_tol!r}"
            )
        for name, allowed in (
            ("mu0_rule", ("gradient_balance", "per_step")),
            ("start_states", ("observations", "sign_of_x0")),
            ("ridge_test", ("location", "value")),
        ):
            if getattr(self, name) not in allowed:
                raise ValueError(
                    f"joint-MAP setting {name}={getattr(self, name)!r} must be one "
                    f"of {list(allowed)}"
                )
        if self.eigen_method not in ("lanczos", "dense"):
            raise ValueError(
                f"joint-MAP setting eigen_method={self.eigen_method!r} must be 'lanczos' or 'dense'"
            )
        if self.pd_tol < 0:
            raise ValueError(f"joint-MAP setting pd_tol={self.pd_tol!r} must be >= 0")
        if self.chunk_size < 0:
            raise ValueError(f"joint-MAP setting chunk_size={self.chunk_size!r} must be >= 0")

    @classmethod
    def from_mapping(cls, values: Mapping[str, Any] | None) -> JointMapSettings:
        """Settings from a config block; unknown keys raise ValueError naming them."""
        values = dict(values or {})
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(values) - known)
        if unknown:
            raise ValueError(f"unknown joint-MAP setting(s) {unknown}; known: {sorted(known)}")
        return cls(**values)

    def as_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    def initial_mu(self, T: int) -> float:
        """mu_0 of the ``per_step`` rule for trajectories of length T."""
        return max(self.mu0, self.mu0_per_step * T)


# =========================================================================== result
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


class _ProgressLike(Protocol):
    def update(self, n: int = 1) -> None: ...


# =========================================================================== Newton direction
def _damped_newton_direction(
    A: np.ndarray,
    C: np.ndarray,
    Dd: np.ndarray,
    Dl: np.ndarray,
    g: np.ndarray,
    settings: JointMapSettings,
    tau_hint: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Newton direction d = -(H + tau I)^{-1} g with the smallest tried tau making H + tau I PD.

    Tries tau = 0 (or tau_hint / 10, the previous iteration's shift reduced, where that is
    above the first shift), then damping_init * (1 + max |H_jj|) times 10, 100, ...
    Returns d (K, n) and tau (K,); where no shift works, d is the scaled steepest-descent
    direction and tau is inf.
    """
    K = g.shape[0]
    scale = 1.0 + np.maximum(
        np.abs(np.diagonal(A, axis1=1, axis2=2)).max(axis=1),
        np.abs(np.diagonal(Dd, axis1=2, axis2=3)).max(axis=(1, 2)),
    )
    first = settings.damping_init * scale
    tau = np.zeros(K)
    if tau_hint is not None:
        hint = np.where(np.isfinite(tau_hint), tau_hint, 0.0) / 10.0
        tau = np.where(hint >= first, hint, 0.0)
    fac = ArrowFactor(A, C, Dd, Dl, tau=tau if tau.any() else None, rhs=-g)
    d = fac.solve_rhs()
    ok = fac.ok & np.all(np.isfinite(d), axis=1)
    if ok.all():
        return d, tau
    bad = np.flatnonzero(~ok)
    t_bad = np.maximum(first[bad], 10.0 * tau[bad])
    for _ in range(settings.max_damping_tries):
        fac = ArrowFactor(A[bad], C[bad], Dd[bad], Dl[bad], tau=t_bad, rhs=-g[bad])
        db = fac.solve_rhs()
        okb = fac.ok & np.all(np.isfinite(db), axis=1)
        d[bad[okb]] = db[okb]
        tau[bad[okb]] = t_bad[okb]
        bad, t_bad = bad[~okb], t_bad[~okb] * 10.0
        if bad.size == 0:
            return d, tau
    d[bad] = -g[bad] / scale[bad, None]
    tau[bad] = np.inf
    return d, tau


# =========================================================================== barrier
class _Barrier:
    """Log barrier -sum log s_i(Omega) for the finite prior bounds and model constraints."""

    def __init__(self, model: StateSpaceModel, bounds: PriorBounds) -> None:
        self.model = model
        self.m = model.n_params
        self.lower = np.asarray(bounds.lower, dtype=float)
        self.upper = np.asarray(bounds.upper, dtype=float)
        self.lo_idx = np.flatnonzero(np.isfinite(self.lower))
        self.up_idx = np.flatnonzero(np.isfinite(self.upper))
        self.constraints = compile_model(model).constraints

    def slacks(self, omega: np.ndarray) -> np.ndarray:
        """(K, n_s) slacks (box lower, box upper, model constraints); all > 0 inside.

        Values only (no derivatives): this is what the line search evaluates.
        """
        parts = [
            omega[:, self.lo_idx] - self.lower[self.lo_idx],
            self.upper[self.up_idx] - omega[:, self.up_idx],
        ]
        if self.constraints.count:
            parts.append(self.constraints.values(omega))
        return np.concatenate(parts, axis=1)

    def slack_gradients(self, omega: np.ndarray) -> np.ndarray:
        """(K, n_s, m) gradients of the slacks, in the order of :meth:`slacks`."""
        K, m = omega.shape
        parts = [
            np.broadcast_to(np.eye(m)[self.lo_idx], (K, self.lo_idx.size, m)),
            np.broadcast_to(-np.eye(m)[self.up_idx], (K, self.up_idx.size, m)),
        ]
        if self.constraints.count:
            parts.append(self.constraints.derivatives(omega)[0])
        return np.concatenate(parts, axis=1)

    def value(self, omega: np.ndarray) -> np.ndarray:
        """(K,) -sum log s_i, +inf where a slack is not positive."""
        s = self.slacks(omega)
        with np.errstate(all="ignore"):
            phi = -np.sum(np.log(np.where(s > 0, s, 1.0)), axis=1)
        return np.where(np.all(s > 0, axis=1), phi, np.inf)

    def derivatives(self, omega: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """value (K,), gradient (K, m) and Hessian (K, m, m) of -sum log s_i."""
        K, m = omega.shape
        grad = np.zeros((K, m))
        hess = np.zeros((K, m, m))
        phi = np.zeros(K)
        with np.errstate(all="ignore"):
            s_lo = omega[:, self.lo_idx] - self.lower[self.lo_idx]
            s_up = self.upper[self.up_idx] - omega[:, self.up_idx]
            phi -= np.log(s_lo).sum(axis=1) + np.log(s_up).sum(axis=1)
            grad[:, self.lo_idx] -= 1.0 / s_lo
            grad[:, self.up_idx] += 1.0 / s_up
            diag = np.zeros((K, m))
            diag[:, self.lo_idx] += 1.0 / s_lo**2
            diag[:, self.up_idx] += 1.0 / s_up**2
            hess += diag[:, :, None] * np.eye(m)
            if self.constraints.count:
                c = self.constraints.values(omega)
                dc, d2c = self.constraints.derivatives(omega)
                phi -= np.log(c).sum(axis=1)
                grad -= np.einsum("kj,kji->ki", 1.0 / c, dc)
                hess += np.einsum("kj,kji,kjl->kil", 1.0 / c**2, dc, dc) - np.einsum(
                    "kj,kjil->kil", 1.0 / c, d2c
                )
        return phi, grad, hess

    def max_step(self, omega: np.ndarray, d_omega: np.ndarray, tau: float) -> np.ndarray:
        """(K,) largest alpha <= 1 keeping a fraction (1 - tau) of every box slack."""
        alpha = np.ones(omega.shape[0])
        with np.errstate(all="ignore"):
            for idx, s, rate in (
                (
                    self.lo_idx,
                    omega[:, self.lo_idx] - self.lower[self.lo_idx],
                    -d_omega[:, self.lo_idx],
                ),
                (
                    self.up_idx,
                    self.upper[self.up_idx] - omega[:, self.up_idx],
                    d_omega[:, self.up_idx],
                ),
            ):
                if idx.size:
                    lim = np.where(rate > 0, tau * s / rate, np.inf)
                    alpha = np.minimum(alpha, lim.min(axis=1))
        return alpha


# =========================================================================== optimiser
def _optimize(
    model: StateSpaceModel,
    z: np.ndarray,
    theta0: np.ndarray,
    barrier: _Barrier,
    settings: JointMapSettings,
    mu_start: float | np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Batched primal barrier-Newton minimisation of -2 pi from ``theta0``.

    Returns theta (K, n), iterations (K,), final mu (K,) and the stop reason (K,) str:
    converged, max-iter, line-search, non-finite, diverged, at-boundary.
    """
    K, n = theta0.shape
    m = model.n_params
    theta = theta0.astype(float).copy()
    mu = np.broadcast_to(np.asarray(mu_start, dtype=float), (K,)).copy()
    iters = np.zeros(K, dtype=np.int64)
    reason = np.full(K, "max-iter", dtype=object)
    active = np.ones(K, dtype=bool)
    tau_last = np.zeros(K)
    eps = np.finfo(float).eps

    def grad_p(g: np.ndarray, bg: np.ndarray, mu_a: np.ndarray) -> np.ndarray:
        gp = g.copy()
        gp[:, :m] += mu_a[:, None] * bg
        return gp

    for _ in range(settings.max_newton_iter):
        act = np.flatnonzero(active)
        if act.size == 0:
            break
        th, zz, mu_a = theta[act], z[act], mu[act]
        f, g, blk = neg2_log_posterior_blocks(model, th, zz)
        phi, bg, bh = barrier.derivatives(th[:, :m])
        finite = (
            np.isfinite(f)
            & np.isfinite(phi)
            & np.all(np.isfinite(g), axis=1)
            & np.all(np.isfinite(bg), axis=1)
        )
        gp = grad_p(g, bg, mu_a)
        gnorm = np.abs(gp).max(axis=1)
        # finish barrier stages whose inner problem is solved, possibly several at once
        while True:
            tol = np.maximum(settings.inner_tol_factor * mu_a, settings.newton_tol)
            lower_mu = finite & (gnorm <= tol) & (mu_a > settings.mu_min)
            if not lower_mu.any():
                break
            mu_a = np.where(lower_mu, np.maximum(mu_a * settings.mu_factor, settings.mu_min), mu_a)
            gp = grad_p(g, bg, mu_a)
            gnorm = np.abs(gp).max(axis=1)
        mu[act] = mu_a
        done = finite & (gnorm <= settings.newton_tol) & (mu_a <= settings.mu_min)
        reason[act[~finite]] = "non-finite"
        reason[act[done]] = "converged"
        active[act[~finite | done]] = False
        go = finite & ~done
        if not go.any():
            continue
        sel = np.flatnonzero(go)
        idx = act[sel]
        th, zz, mu_s, gps = th[sel], zz[sel], mu_a[sel], gp[sel]
        P0 = f[sel] + mu_s * phi[sel]
        A = blk.omega[sel] + mu_s[:, None, None] * bh[sel]
        d, tau_used = _damped_newton_direction(
            A, blk.cross[sel], blk.diag[sel], blk.lower[sel], gps, settings, tau_last[idx]
        )
        tau_last[idx] = tau_used
        slope = np.einsum("kj,kj->k", gps, d)
        uphill = ~(slope < 0)
        if uphill.any():  # safeguard: never search along an ascent direction
            d[uphill] = -gps[uphill]
            slope[uphill] = -np.einsum("kj,kj->k", gps[uphill], gps[uphill])
        # a full step smaller than rounding at mu_min: nothing left to gain
        tiny = (np.abs(d).max(axis=1) <= 4 * eps * (1.0 + np.abs(th).max(axis=1))) & (
            mu_s <= settings.mu_min
        )
        if tiny.any():
            reason[idx[tiny]] = "converged"
            active[idx[tiny]] = False
        alpha = barrier.max_step(th[:, :m], d[:, :m], settings.fraction_to_boundary)
        accepted = np.zeros(sel.size, dtype=bool)
        pending = ~tiny
        for _ls in range(settings.max_backtracks):
            pi = np.flatnonzero(pending)
            if pi.size == 0:
                break
            trial = th[pi] + alpha[pi, None] * d[pi]
            (ft,) = neg2_log_posterior(model, trial, zz[pi], None, order=0)
            Pt = ft + mu_s[pi] * barrier.value(trial[:, :m])
            ok = np.isfinite(Pt) & (
                Pt
                <= P0[pi] + settings.armijo_c1 * alpha[pi] * slope[pi] + 16 * eps * np.abs(P0[pi])
            )
            good = pi[ok]
            theta[idx[good]] = trial[ok]
            accepted[good] = True
            pending[good] = False
            alpha[pi[~ok]] *= 0.5
        stuck = pending  # never accepted
        reason[idx[stuck]] = "line-search"
        active[idx[stuck]] = False
        iters[idx[accepted]] += 1
        big = np.abs(theta[idx]).max(axis=1) > settings.divergence_limit
        reason[idx[big]] = "diverged"
        active[idx[big]] = False
        s_now = barrier.slacks(theta[idx, :m])
        if s_now.shape[1]:
            edge = ~big & (s_now.min(axis=1) < settings.boundary_stop_tol)
            reason[idx[edge]] = "at-boundary"
            active[idx[edge]] = False
    return theta, iters, mu, reason


def _chunks(K: int, n: int, settings: JointMapSettings) -> list[slice]:
    """Contiguous batches of k; memory per trajectory is O(n (lanczos_steps + (m + 2p)^2))."""
    size = settings.chunk_size or int(np.clip(2e5 / n, 64, 2048))
    return [slice(s, min(s + size, K)) for s in range(0, K, size)]


def _classify_chunk(
    model: StateSpaceModel,
    z: np.ndarray,
    theta: np.ndarray,
    mu: np.ndarray,
    stop: np.ndarray,
    barrier: _Barrier,
    settings: JointMapSettings,
) -> dict[str, np.ndarray]:
    """Checks of Sec. III.B for one chunk (ridge re-optimisation included)."""
    K, n = theta.shape
    m = model.n_params
    with np.errstate(all="ignore"):
        f, g, blk = neg2_log_posterior_blocks(model, theta, z)
    fin_h = np.ones(K, dtype=bool)
    for a in (blk.omega, blk.cross, blk.diag, blk.lower):
        fin_h &= np.all(np.isfinite(a.reshape(K, -1)), axis=1)
    finite = (
        np.isfinite(f) & np.all(np.isfinite(g), axis=1) & fin_h & np.all(np.isfinite(theta), axis=1)
    )
    fac = ArrowFactor(blk.omega, blk.cross, blk.diag, blk.lower)
    fac.ok &= finite
    lam_min, lam_max, v_min = arrow_extreme_eigenpairs(
        fac, settings.eigen_method, settings.lanczos_steps
    )
    with np.errstate(all="ignore"):
        ratio = lam_min / lam_max
        grad_max = np.abs(g).max(axis=1)
        s = barrier.slacks(theta[:, :m])
        s_min = s.min(axis=1) if s.shape[1] else np.full(K, np.inf)
        mult = np.where(stop == "converged", mu / s_min, 0.0)
        # rate of decrease of -2 pi when moving towards each constraint (unit normal)
        ds = barrier.slack_gradients(theta[:, :m])
        pull = np.einsum("ki,ksi->ks", g[:, :m], ds) / np.maximum(
            np.linalg.norm(ds, axis=2), 1e-300
        )
        pushed = np.any((s < settings.boundary_near_tol) & (pull > settings.grad_tol), axis=1)
        pushed &= stop != "converged"
        lvar = 2.0 * fac.diag_inverse()
    pd_ = fac.ok & (lam_min > settings.pd_tol)
    lvar[~pd_] = np.nan

    status = np.full(K, "ok", dtype=object)
    reason = np.full(K, "", dtype=object)
    undecided = np.ones(K, dtype=bool)

    def assign(mask: np.ndarray, st: str, why: str | Callable[[np.intp], str]) -> None:
        nonlocal undecided
        hit = mask & undecided
        status[hit] = st
        for k in np.flatnonzero(hit):
            reason[k] = why(k) if callable(why) else why
        undecided &= ~hit

    assign(
        ~finite,
        "failed",
        lambda k: f"non-finite value/gradient/Hessian at the result (optimiser stop: {stop[k]})",
    )
    assign(
        stop == "diverged",
        "boundary",
        f"iterates ran off to infinity (|Theta|_inf > {settings.divergence_limit:g})",
    )
    assign(
        s_min < settings.boundary_tol,
        "boundary",
        lambda k: f"optimum on the boundary of the prior support (min slack {s_min[k]:.3g})",
    )
    assign(
        mult > settings.grad_tol,
        "boundary",
        lambda k: f"barrier holds the optimum (mu/slack = {mult[k]:.3g})",
    )
    assign(
        pushed,
        "boundary",
        lambda k: (
            f"-2 pi still decreases towards the boundary (min slack {s_min[k]:.3g}, "
            f"optimiser stop: {stop[k]})"
        ),
    )
    assign(
        ~pd_,
        "not-positive-definite",
        lambda k: f"Hessian not positive definite (smallest eigenvalue about {lam_min[k]:.3g})",
    )
    assign(
        ~(grad_max < settings.grad_tol),
        "gradient",
        lambda k: (
            f"max |gradient| {grad_max[k]:.3g} >= {settings.grad_tol:g} (optimiser stop: {stop[k]})"
        ),
    )

    cand = np.flatnonzero(undecided & ~(ratio >= settings.eig_ratio_min))
    value_change = np.full(K, np.nan)
    if cand.size:
        ridge, dist, dval = _ridge_check(
            model, z[cand], theta[cand], f[cand], v_min[cand], barrier, settings
        )
        value_change[cand] = dval
        for j, k in enumerate(cand):
            small = f"eigenvalue ratio {ratio[k]:.3g} < {settings.eig_ratio_min:g}"
            what = f"moved {dist[j]:.3g} (sup norm), -2 pi changed by {dval[j]:.3g}"
            if ridge[j]:
                status[k] = "ridge"
                reason[k] = f"{small}; after a shift along the ridge the re-optimisation {what}"
            else:
                reason[k] = (
                    f"{small} but the re-optimisation returned ({what}; "
                    f"test: {settings.ridge_test})"
                )
    return dict(
        neg2_log_post=f,
        local_variance=lvar,
        eig_ratio=ratio,
        grad_max=grad_max,
        status=status,
        reason=reason,
        ridge_value_change=value_change,
    )


def _ridge_check(
    model: StateSpaceModel,
    z: np.ndarray,
    theta: np.ndarray,
    f_hat: np.ndarray,
    v: np.ndarray,
    barrier: _Barrier,
    settings: JointMapSettings,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Re-optimise from Theta_hat + h v (or - h v if that leaves the support).

    Returns (ridge, distance moved (sup norm), |change of -2 pi|); ``ridge`` by
    ``settings.ridge_test``.  A non-finite or diverged re-optimisation counts as a ridge.
    """
    m = model.n_params
    start = theta.copy()
    placed = np.zeros(theta.shape[0], dtype=bool)
    h = settings.ridge_shift
    for _ in range(30):
        for sign in (1.0, -1.0):
            trial = theta + sign * h * v
            inside = ~placed & np.isfinite(barrier.value(trial[:, :m]))
            start[inside] = trial[inside]
            placed |= inside
        if placed.all():
            break
        h *= 0.5
    new, _, _, stop = _optimize(model, z, start, barrier, settings, settings.mu_min)
    with np.errstate(all="ignore"):
        dist = np.abs(new - theta).max(axis=1)
        (f_new,) = neg2_log_posterior(model, new, z, None, order=0)
        dval = np.abs(f_new - f_hat)
    if settings.ridge_test == "location":
        differs = ~(dist <= settings.ridge_move_tol)
    else:
        differs = ~(dval <= settings.ridge_value_tol * (1.0 + np.abs(f_hat)))
    ridge = differs | (stop == "non-finite") | (stop == "diverged")
    return ridge, dist, dval


# =========================================================================== public API
def initial_theta(
    model: StateSpaceModel,
    z: np.ndarray,
    omega_true: np.ndarray,
    x0_true: np.ndarray,
    start_states: str = "observations",
) -> np.ndarray:
    """Start of Sec. III.B: (Omega_true, x0_true, initial_states(Omega_true, z)) for every k.

    ``start_states="sign_of_x0"``: the states start at
    ``model.sign_consistent_states(Omega_true, x0_true, z)`` instead.
    """
    K, T, _ = z.shape
    if start_states == "sign_of_x0":
        x = np.asarray(model.sign_consistent_states(omega_true, x0_true, z), dtype=float)
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


def initial_mu_values(
    model: StateSpaceModel,
    z: np.ndarray,
    theta0: np.ndarray,
    barrier: _Barrier,
    settings: JointMapSettings,
) -> np.ndarray:
    """(K,) barrier start mu_0 of every trajectory (``settings.mu0_rule``).

    ``gradient_balance``: mu_0 = ||grad_Omega(-2 pi)(Theta_0)||_2 / ||grad_Omega B(Theta_0)||_2,
    the mu at which the barrier holds half of P_mu's Omega-gradient at the start, floored
    at ``mu_min`` (and ``mu_min`` where there is no barrier or the ratio is not finite).
    ``per_step``: max(mu0, mu0_per_step * T) for every k.
    """
    K, T = z.shape[0], z.shape[1]
    if settings.mu0_rule == "per_step":
        return np.full(K, settings.initial_mu(T))
    m = model.n_params
    with np.errstate(all="ignore"):
        _, g = neg2_log_posterior(model, theta0, z, None, order=1)[:2]
        _, bg, _ = barrier.derivatives(theta0[:, :m])
        mu0 = np.linalg.norm(g[:, :m], axis=1) / np.linalg.norm(bg, axis=1)
    return np.where(np.isfinite(mu0), np.maximum(mu0, settings.mu_min), settings.mu_min)


def joint_map(
    model: StateSpaceModel,
    z: np.ndarray,
    bounds: PriorBounds,
    omega_true: np.ndarray,
    x0_true: np.ndarray,
    settings: JointMapSettings | None = None,
    progress: _ProgressLike | None = None,
) -> JointMapResult:
    """Joint MAP estimate and numerical checks for every design trajectory (Sec. III.B).

    Parameters
    ----------
    model : the state space model.
    z : (K, T, d) design observation trajectories z~(k).
    bounds : support of the flat prior on Omega (from ``model.prior_bounds``).
    omega_true, x0_true : true values; they are the start of every optimisation.
    settings : thresholds and tuning (:class:`JointMapSettings`; defaults = paper values).
    progress : optional object with ``update(n)`` (e.g. :class:`ssmobs.log.Progress`),
        called after each batch with the number of trajectories finished.

    Returns
    -------
    JointMapResult with per-k arrays; ``status == "ok"`` marks K^max.  A numerical failure
    of one trajectory never raises: it is recorded as ``failed`` with a reason.
    """
    settings = settings or JointMapSettings()
    z = np.asarray(z, dtype=float)
    if z.ndim != 3 or z.shape[2] != model.obs_dim:
        raise ValueError(
            f"z must have shape (K, T, {model.obs_dim}) for model '{model.slug}', got {z.shape}"
        )
    K, T, _ = z.shape
    omega = np.asarray(omega_true, dtype=float)
    x0 = np.atleast_1d(np.asarray(x0_true, dtype=float))
    if omega.shape != (model.n_params,):
        raise ValueError(
            f"omega_true must have {model.n_params} value(s) in the order "
            f"{list(model.param_names)}, got {omega.tolist()}"
        )
    if x0.shape != (model.state_dim,):
        raise ValueError(f"x0_true must have {model.state_dim} component(s), got {x0.tolist()}")
    barrier = _Barrier(model, bounds)
    if not np.isfinite(barrier.value(omega[None, :]))[0]:
        raise ValueError(
            f"start Omega={omega.tolist()} is not strictly inside the prior support "
            f"({bounds.lower.tolist()}, {bounds.upper.tolist()}) and the model "
            f"constraints"
        )
    n = model.n_theta(T)
    out = JointMapResult(
        theta_hat=np.full((K, n), np.nan),
        neg2_log_post=np.full(K, np.nan),
        local_variance=np.full((K, n), np.nan),
        eig_ratio=np.full(K, np.nan),
        grad_max=np.full(K, np.nan),
        iterations=np.zeros(K, dtype=np.int64),
        status=np.full(K, "failed", dtype=object),
        reason=np.full(K, "", dtype=object),
        theta_names=model.theta_names(T),
        mu_start=np.full(K, np.nan),
        ridge_value_change=np.full(K, np.nan),
    )
    for sl in _chunks(K, n, settings):
        zc = z[sl]
        theta0 = initial_theta(model, zc, omega, x0, settings.start_states)
        mu_start = initial_mu_values(model, zc, theta0, barrier, settings)
        theta, iters, mu, stop = _optimize(model, zc, theta0, barrier, settings, mu_start)
        res = _classify_chunk(model, zc, theta, mu, stop, barrier, settings)
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
    as the Stan stage's :func:`ssmobs.stan_metrics.stan_summary`): ``c_mean``, ``c_var``
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
