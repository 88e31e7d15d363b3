"""Settings of the joint MAP (Sec. III.B): the thresholds of its checks and the tuning of
its barrier solver.

One frozen dataclass, read from the config's ``joint_map`` block, for the solver
(:mod:`ssmobs.joint_map.barrier`), the checks of a found maximum
(:mod:`ssmobs.joint_map.checks`) and the driver (:mod:`ssmobs.joint_map.driver`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np


@dataclass(frozen=True)
class JointMapSettings:
    """Thresholds and tuning of the joint-MAP optimiser and its checks (Sec. III.B).

    The config's ``joint_map`` block (``workflow/schemas/config.schema.yaml``) sets the
    paper's thresholds and the choices a study varies (the start of the barrier, the ridge
    test); every key of it is a field (a test compares the two).

    Fixed fields, not in the config (code that calls :func:`ssmobs.joint_map.driver.joint_map`
    itself may set them):

    - ``start_states``: set per scenario instead (its ``joint_map_start``);
    - the solver's numerics, how the optimum and the Hessian's extreme eigenvalues are
      computed: ``newton_tol``, ``inner_tol_factor``, ``mu_factor``, ``mu_min``,
      ``fraction_to_boundary``, ``armijo_c1``, ``max_backtracks``, ``damping_init``,
      ``max_damping_tries``, ``eigen_method``, ``lanczos_steps``;
    - the thresholds of our checks that the paper does not name: ``pd_tol``,
      ``ridge_shift``, ``boundary_tol``, ``boundary_stop_tol``, ``boundary_near_tol``,
      ``divergence_limit``, ``runoff_iter``, ``runoff_reach``, ``runoff_margin``.

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
    #: equals that of -2 pi at the start; :mod:`ssmobs.joint_map.barrier`) or "per_step"
    #: (the formula above)
    mu0_rule: str = "gradient_balance"
    #: start of the states: "observations" (the paper's x = z), "sign_of_x0"
    #: (model.sign_consistent_states; only models that define it) or "simulate" (the
    #: model's noise-free path from x_0; the multi-start's extra starts)
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
    #: |Theta|_inf above this means the iterates run off to infinity (status unbounded)
    divergence_limit: float = 1e6
    #: a run stopped by max_newton_iter or the line search is followed for this many more
    #: iterations to tell a run-off (unbounded) or a flat direction (ridge) from a slow
    #: convergence (:func:`ssmobs.joint_map.checks.runoff_check`)
    runoff_iter: int = 50
    #: a continued segment of that run counts as diverged only past this many times its
    #: start's |Theta|_inf (and never below divergence_limit), so that a run that passed
    #: divergence_limit is followed too and its gain measured
    runoff_reach: float = 100.0
    #: a continued segment is flat (a ridge) when -2 pi changes by at most
    #: ridge_value_tol * (1 + |-2 pi|) / runoff_margin, and gains when it falls by more than
    #: ridge_value_tol * (1 + |-2 pi|): between the two the label stays ``gradient``, so that
    #: no change of -2 pi at the level of rounding moves a run from one label to another
    runoff_margin: float = 100.0
    #: extreme eigenvalues of the Hessian: "lanczos" (structured, O(n) per step) or "dense"
    eigen_method: str = "lanczos"
    #: Lanczos steps (exact spectrum when >= |Theta|)
    lanczos_steps: int = 24
    #: trajectories per vectorised batch (0: about 2e5 / |Theta|, between 64 and 2048)
    chunk_size: int = 0
    #: starts per trajectory (:mod:`ssmobs.joint_map.multi_start`): 1 is the paper's start alone; n
    #: > 1
    #: adds n - 1 starts spread over the start box by a Halton sequence
    n_starts: int = 1
    #: two maxima that pass the checks are one if no component of Theta differs by more
    #: than this many local standard deviations sqrt(LVar_j) (:mod:`ssmobs.joint_map.multi_start`)
    distinct_tol: float = 1e-2
    #: a trajectory has one maximum (K^max_unique) only when at least this share of its
    #: n_starts starts pass the checks and all reach it; with fewer it is "undetermined"
    unique_min_share: float = 0.5
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
            "runoff_iter",
        ):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"joint-MAP setting {name}={getattr(self, name)!r} must be >= 1")
        for name in ("runoff_reach", "runoff_margin"):
            if not (np.isfinite(getattr(self, name)) and getattr(self, name) >= 1):
                raise ValueError(
                    f"joint-MAP setting {name}={getattr(self, name)!r} must be a number >= 1"
                )
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
            ("start_states", ("observations", "sign_of_x0", "simulate")),
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
        if not 0 < self.unique_min_share <= 1:
            raise ValueError(
                f"joint-MAP setting unique_min_share={self.unique_min_share!r} must be in (0, 1]"
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
