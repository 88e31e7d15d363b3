"""The model contract shared by every state space model of Section IV.

A model of the form (1) of the paper,

    Z_t = g(Omega, X_t, eps_t),   X_t = h(Omega, X_{t-1}, eta_t),   t = 1..T,

is given by its dimensions (d observations, p states), its parameter names Omega, a
simulator (Eq. (1), used in Sec. III.A to turn design disturbances into design
trajectories) and the two per-time-step terms of the log posterior (2):

    -2 pi(Theta | z) = sum_t obs_term(Omega, x_t; z_t) + sum_t trans_term(Omega, x_{t-1}, x_t)
                       - 2 log p(Omega) + const,

with Theta = (Omega, x_0, x_1, ..., x_T).  The prior of x_0 is flat (Sec. IV), those of Omega
uniform on intervals (Eq. (3), (14)): their support enters as bounds.  The per-step terms are
written once in SymPy; :mod:`ssmobs.models.log_posterior` assembles value, gradient and
Hessian for a batch of trajectories from them.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
import numpy.typing as npt
import sympy as sp

#: prior variants for a parameter Omega_i (Sec. II.A Example 1 and Sec. IV.E):
#: ``restricted``: U(0, 1) if the true value is positive, U(-1, 0) if negative (Eq. (3));
#: ``unrestricted``: U(-1, 1);
#: ``half_line``: flat on (0, inf) if the true value is positive, (-inf, 0) if negative (Eq. (14)).
PRIOR_VARIANTS: tuple[str, ...] = ("restricted", "unrestricted", "half_line")

#: the prior of one parameter as a config gives it: a variant name, or an interval
#: [lower, upper] of a flat prior (either bound may be infinite; issue 47)
PriorChoice = str | Sequence[float]


def interval_label(lower: float, upper: float) -> str:
    """The name of a flat prior on (lower, upper), as :attr:`PriorBounds.variants` shows it."""
    return f"interval({lower:g}, {upper:g})"


#: Largest |true value| and |noise-free state or observation| a scenario may have: the terms
#: of -2 log pi then stay below about 1e8, so double precision keeps 8 significant digits in
#: the differences that the joint MAP's Newton steps and the model check compare.
MAX_MAGNITUDE = 1e4
MAGNITUDE_REASON = "beyond it double precision cannot resolve the log posterior's differences"


class ModelDefinitionError(ValueError):
    """A model module breaks the model contract; the message names the file and the problem."""


@dataclass(frozen=True)
class PriorBounds:
    """Support of the (flat) prior on Omega: ``lower < Omega < upper`` component-wise."""

    lower: np.ndarray
    upper: np.ndarray
    variants: tuple[str, ...]

    def contains(self, omega: np.ndarray) -> np.ndarray:
        """True where ``omega`` (shape (..., m)) lies strictly inside the support."""
        omega = np.asarray(omega, dtype=float)
        return np.all((omega > self.lower) & (omega < self.upper), axis=-1)


def ar1_states(coef: npt.ArrayLike, x0: np.ndarray, eta: np.ndarray) -> np.ndarray:
    """States of X_t = c X_{t-1} + sqrt(1 - c^2) eta_t (component-wise c), t = 1..T.

    ``coef`` is a scalar or (p,), ``x0`` (p,), ``eta`` (K, T, p); returns (K, T, p).
    """
    coef = np.broadcast_to(np.asarray(coef, dtype=float), (eta.shape[2],))
    scale = np.sqrt(1 - coef**2)
    x = np.empty_like(eta, dtype=float)
    prev = np.broadcast_to(np.asarray(x0, dtype=float), eta.shape[::2])
    for t in range(eta.shape[1]):
        prev = coef * prev + scale * eta[:, t, :]
        x[:, t, :] = prev
    return x


class StateSpaceModel:
    """Base class of a model of Section IV; a subclass is one paper model.

    Subclasses set the class attributes and implement :meth:`obs_term`,
    :meth:`trans_term` and :meth:`simulate`; optional :meth:`support_constraints`.
    """

    slug: ClassVar[str]
    title: ClassVar[str]
    obs_dim: ClassVar[int]
    state_dim: ClassVar[int]
    param_names: ClassVar[tuple[str, ...]]
    #: prior of each parameter a config leaves out: a variant (the paper's choice) or an
    #: interval (lower, upper), bounds possibly infinite (``(-math.inf, math.inf)``: flat)
    default_prior: ClassVar[Mapping[str, PriorChoice]]
    #: prior variants that make sense for each parameter
    allowed_priors: ClassVar[Mapping[str, tuple[str, ...]]]
    #: parameters that enter as sqrt(1 - w^2) and so need |w| < 1
    unit_interval_params: ClassVar[tuple[str, ...]] = ()
    #: parameters that must be strictly positive whatever the prior (e.g. sqrt(a))
    positive_params: ClassVar[tuple[str, ...]] = ()
    #: readable form of each expression of :meth:`support_constraints`, for messages
    constraint_text: ClassVar[tuple[str, ...]] = ()
    #: True when, for fixed Omega, the model is linear and Gaussian in the states (then
    #: :meth:`state_space_matrices` gives it and :mod:`ssmobs.exact.marginal` applies)
    linear_in_states: ClassVar[bool] = False

    # ----------------------------------------------------------------- symbolic terms
    def obs_term(
        self, omega: Sequence[sp.Symbol], x: Sequence[sp.Symbol], z: Sequence[sp.Symbol]
    ) -> sp.Expr:
        """-2 log f_z(z_t | x_t, Omega), up to an additive constant."""
        raise NotImplementedError

    def trans_term(
        self, omega: Sequence[sp.Symbol], x_prev: Sequence[sp.Symbol], x: Sequence[sp.Symbol]
    ) -> sp.Expr:
        """-2 log p_x(x_t | x_{t-1}, Omega), up to an additive constant."""
        raise NotImplementedError

    def support_constraints(self, omega: Sequence[sp.Symbol]) -> list[sp.Expr]:
        """Expressions c(Omega) that must be > 0 besides the prior box (e.g. 1 - a^2 - b^2)."""
        return []

    def state_space_matrices(
        self, omega: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Linear-Gaussian form for models with :attr:`linear_in_states`, batched over Omega.

        ``omega`` (..., m) gives F (..., p, p), state-noise variances Q (..., p), H (..., d, p)
        and observation-noise variances R (..., d) of

            x_t = F x_{t-1} + N(0, diag Q),   z_t = H x_t + N(0, diag R).
        """
        raise NotImplementedError(f"model '{self.slug}' is not linear-Gaussian in the states")

    # ----------------------------------------------------------------- simulation
    def simulate(
        self, omega: np.ndarray, x0: np.ndarray, eta: np.ndarray, eps: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """States and observations for disturbances (Eq. (1); Sec. III.A).

        Parameters
        ----------
        omega : (m,) true parameters.
        x0 : (p,) true initial state.
        eta : (K, T, p) state disturbances.
        eps : (K, T, d) observation disturbances.

        Returns
        -------
        x : (K, T, p) states x_1..x_T;  z : (K, T, d) observations z_1..z_T.
        """
        raise NotImplementedError

    def initial_states(self, omega: np.ndarray, z: np.ndarray) -> np.ndarray:
        """Start values of x_1..x_T for the joint-MAP optimisation (Sec. III.B).

        The paper starts the k-th optimisation at (Omega_true, x0_true, z~(k)): the
        observations themselves serve as the start of the states.  That needs d == p;
        models with d != p override this method and document their choice.

        Parameters
        ----------
        omega : (m,) parameter values of the start (Omega_true); unused here.
        z : (K, T, d) observation trajectories.

        Returns
        -------
        (K, T, p) start values of the states.
        """
        z = np.asarray(z, dtype=float)
        if self.obs_dim != self.state_dim:
            raise NotImplementedError(
                f"model '{self.slug}' has d={self.obs_dim} != p={self.state_dim} and must "
                f"override initial_states"
            )
        return z.copy()

    #: True where :meth:`sign_consistent_states` is defined
    has_sign_consistent_start: bool = False

    def sign_consistent_states(
        self, omega: np.ndarray, x0: np.ndarray, z: np.ndarray
    ) -> np.ndarray:
        """Alternative start of the states whose signs agree with x0 (see the models)."""
        raise NotImplementedError(
            f"model '{self.slug}' defines no sign-consistent start; "
            f"use joint_map_start: observations"
        )

    def mirror_images(self, theta: np.ndarray) -> list[np.ndarray]:
        """Images of Theta = (Omega, x_0, x_1..x_T), rows (K, |Theta|), under symmetries of
        the model (maps that leave -2 pi unchanged for every z) *outside* the families the
        workflow searches; none by default.

        Sign changes, permutations of interchangeable blocks, translations by a period and
        reflections such as x -> pi - x are found from :meth:`obs_term` and :meth:`trans_term`
        (:func:`ssmobs.models.symmetries.model_symmetries`; docs/method/symmetries.md) and
        need no declaration.  The multi-start (:mod:`ssmobs.joint_map.multi_start`) starts
        again from the images of every maximum it finds, so that a maximum and its image, of
        the same height, are both found and the trajectory is not counted as having one
        maximum; the model check warns about a declared image that no found map gives.
        """
        return []

    # ----------------------------------------------------------------- derived facts
    @property
    def n_params(self) -> int:
        return len(self.param_names)

    def n_theta(self, T: int) -> int:
        """|Theta| = |Omega| + p (T + 1)."""
        return self.n_params + self.state_dim * (T + 1)

    def theta_names(self, T: int) -> list[str]:
        """Names of the components of Theta = (Omega, x_0, x_1..x_T), in order."""
        names = list(self.param_names)
        for t in range(T + 1):
            if self.state_dim == 1:
                names.append(f"x{t}")
            else:
                names.extend(f"x{t}_{i + 1}" for i in range(self.state_dim))
        return names

    def prior_bounds(
        self,
        omega_true: Mapping[str, float] | Sequence[float] | np.ndarray,
        prior: str | Mapping[str, PriorChoice] | None = None,
    ) -> PriorBounds:
        """Bounds of the flat prior on Omega for the given variants (Eq. (3), Eq. (14)).

        ``prior`` is one variant for all parameters, a mapping parameter -> variant or
        interval [lower, upper] (missing parameters take :attr:`default_prior`), or None for
        the paper's choice.  An interval is used as given (flat on (lower, upper), either
        bound possibly infinite), whatever :attr:`allowed_priors` says: the model check
        compares it with the Stan program's bounds.  Raises ValueError naming the parameter
        and value when a variant is unknown, not allowed for the model, or undefined for the
        true value (sign 0), or an interval is not two numbers lower < upper.
        """
        omega = self.omega_array(omega_true)
        variants = self.resolve_prior(prior)
        lower = np.empty(self.n_params)
        upper = np.empty(self.n_params)
        labels: list[str] = []
        for i, (name, variant) in enumerate(zip(self.param_names, variants)):
            value = omega[i]
            if not isinstance(variant, str):
                lower[i], upper[i] = variant
                labels.append(interval_label(*variant))
                continue
            labels.append(variant)
            if variant == "unrestricted":
                lower[i], upper[i] = -1.0, 1.0
                continue
            if value == 0:
                raise ValueError(
                    f"prior '{variant}' for parameter '{name}' of model '{self.slug}' takes its "
                    f"sign from the true value, which is 0; use a non-zero true value or "
                    f"prior 'unrestricted'"
                )
            if variant == "restricted":
                lower[i], upper[i] = (0.0, 1.0) if value > 0 else (-1.0, 0.0)
            else:  # half_line
                lower[i], upper[i] = (0.0, math.inf) if value > 0 else (-math.inf, 0.0)
        return PriorBounds(lower=lower, upper=upper, variants=tuple(labels))

    def resolve_prior(
        self, prior: str | Mapping[str, PriorChoice] | None
    ) -> list[str | tuple[float, float]]:
        """Prior per parameter: a variant validated against :attr:`allowed_priors`, or an
        interval (lower, upper) checked to be two numbers with lower < upper."""
        if prior is None:
            chosen: dict[str, PriorChoice] = dict(self.default_prior)
        elif isinstance(prior, str):
            chosen = {name: prior for name in self.param_names}
        else:
            unknown = sorted(set(prior) - set(self.param_names))
            if unknown:
                raise ValueError(
                    f"prior names parameter(s) {unknown} that model '{self.slug}' does not "
                    f"have; its parameters are {list(self.param_names)}"
                )
            chosen = {**self.default_prior, **prior}
        out: list[str | tuple[float, float]] = []
        for name in self.param_names:
            variant = chosen[name]
            if not isinstance(variant, str):
                out.append(self._interval(name, variant))
                continue
            if variant not in PRIOR_VARIANTS:
                raise ValueError(
                    f"unknown prior variant '{variant}' for parameter '{name}'; "
                    f"allowed: {list(PRIOR_VARIANTS)} or an interval [lower, upper]"
                )
            if variant not in self.allowed_priors[name]:
                raise ValueError(
                    f"prior variant '{variant}' is not allowed for parameter '{name}' of model "
                    f"'{self.slug}'; allowed: {list(self.allowed_priors[name])} or an "
                    f"interval [lower, upper]"
                )
            out.append(variant)
        return out

    @classmethod
    def _interval(cls, name: str, value: object) -> tuple[float, float]:
        """(lower, upper) of an interval prior, or ValueError naming the parameter."""
        try:
            lo, hi = (float(v) for v in value)  # type: ignore[attr-defined]
        except (TypeError, ValueError):
            raise ValueError(
                f"prior of parameter '{name}' of model '{cls.slug}' must be a variant name or "
                f"an interval [lower, upper] of two numbers (.inf allowed), got {value!r}"
            ) from None
        if isinstance(value, str) or math.isnan(lo) or math.isnan(hi) or not lo < hi:
            raise ValueError(
                f"prior interval of parameter '{name}' of model '{cls.slug}' must have "
                f"lower < upper, got {[lo, hi]!r}"
            )
        return lo, hi

    @classmethod
    def default_prior_problems(cls) -> list[str]:
        """Problems of :attr:`default_prior`: each entry one of the parameter's
        :attr:`allowed_priors` or an interval (lower, upper), lower < upper (.inf allowed)."""
        problems = []
        for name in cls.param_names:
            default, allowed = cls.default_prior[name], cls.allowed_priors[name]
            if isinstance(default, str) and default not in allowed:
                what = f"{default!r} is not in allowed_priors[{name!r}] = {allowed!r}"
                problems.append(f"default_prior[{name!r}] = {what} (or give an interval)")
            elif not isinstance(default, str):
                try:
                    cls._interval(name, default)
                except ValueError as err:
                    problems.append(f"default_prior[{name!r}]: {err}")
        return problems

    def check_true_values(
        self,
        omega_true: Mapping[str, float] | Sequence[float],
        x0_true: Sequence[float] | float,
        prior: str | Mapping[str, PriorChoice] | None = None,
        T: int | None = None,
    ) -> list[str]:
        """Problems with true values (empty list when valid): each names key, value and range.

        Magnitudes are bounded by :data:`MAX_MAGNITUDE`: true values, and with ``T`` the
        noise-free trajectory (Eq. (1) with eta = eps = 0) they produce.
        """
        problems: list[str] = []
        try:
            omega = self.omega_array(omega_true)
        except ValueError as err:
            return [str(err)]
        x0 = np.atleast_1d(np.asarray(x0_true, dtype=float))
        if x0.shape != (self.state_dim,):
            problems.append(
                f"x0 must have {self.state_dim} component(s) for model "
                f"'{self.slug}', got {x0.tolist()}"
            )
        if not np.all(np.isfinite(omega)) or not np.all(np.isfinite(x0)):
            problems.append("true values must be finite numbers")
            return problems
        for name, value in [*zip(self.param_names, omega), *(("x0", v) for v in x0)]:
            if abs(value) > MAX_MAGNITUDE:
                problems.append(
                    f"true value {name}={value:g} is too large: |{name}| <= {MAX_MAGNITUDE:g} "
                    f"({MAGNITUDE_REASON})"
                )
        if problems:
            return problems
        for i, name in enumerate(self.param_names):
            if name in self.unit_interval_params and not abs(omega[i]) < 1:
                problems.append(
                    f"true value {name}={omega[i]} must satisfy |{name}| < 1 in model '{self.slug}'"
                )
            if name in self.positive_params and not omega[i] > 0:
                problems.append(f"true value {name}={omega[i]} must be > 0 in model '{self.slug}'")
        syms = sp.symbols(" ".join(f"w{i}" for i in range(self.n_params)), seq=True)
        for i, expr in enumerate(self.support_constraints(list(syms))):
            val = float(expr.subs(dict(zip(syms, omega))))
            if not val > 0:
                text = (
                    self.constraint_text[i]
                    if i < len(self.constraint_text)
                    else sp.sstr(expr.subs(dict(zip(syms, sp.symbols(self.param_names))))) + " > 0"
                )
                problems.append(
                    f"true values {dict(zip(self.param_names, omega.tolist()))} violate the "
                    f"constraint {text} of model '{self.slug}'"
                )
        if problems:
            return problems
        try:
            bounds = self.prior_bounds(omega, prior)
        except ValueError as err:
            return [str(err)]
        for i, name in enumerate(self.param_names):
            if not bounds.lower[i] < omega[i] < bounds.upper[i]:
                problems.append(
                    f"true value {name}={omega[i]} lies outside the support "
                    f"({bounds.lower[i]}, {bounds.upper[i]}) of its prior '{bounds.variants[i]}'"
                )
        if T is not None and not problems:
            zeros = (np.zeros((1, T, self.state_dim)), np.zeros((1, T, self.obs_dim)))
            with np.errstate(all="ignore"):
                x, z = self.simulate(omega, x0, *zeros)
            peak = float(np.max(np.abs(np.concatenate([np.ravel(x), np.ravel(z)]))))
            if not peak <= MAX_MAGNITUDE:
                problems.append(
                    f"true values {dict(zip(self.param_names, omega.tolist()))}, "
                    f"x0={x0.tolist()} reach |x_t| or |z_t| = {peak:g} within T={T} steps "
                    f"without noise; allowed: <= {MAX_MAGNITUDE:g} ({MAGNITUDE_REASON})"
                )
        return problems

    def omega_array(self, omega: Mapping[str, float] | Sequence[float] | np.ndarray) -> np.ndarray:
        """Omega as a float array in :attr:`param_names` order, from the config's mapping
        ``{name: value}`` (exactly the model's parameters) or from a sequence of m values.

        The one conversion of the config's form: :meth:`ssmobs.config.scenario.Scenario.from_config`
        calls it, and everything downstream takes the array.  ValueError names what is
        missing, unknown or of the wrong length.
        """
        if isinstance(omega, Mapping):
            missing = [n for n in self.param_names if n not in omega]
            extra = sorted(set(omega) - set(self.param_names))
            if missing or extra:
                raise ValueError(
                    f"model '{self.slug}' needs true values for exactly {list(self.param_names)}; "
                    f"missing {missing}, unknown {extra}"
                )
            return np.array([float(omega[n]) for n in self.param_names])
        arr = np.asarray(omega, dtype=float).reshape(-1)
        if arr.shape != (self.n_params,):
            raise ValueError(
                f"model '{self.slug}' has {self.n_params} parameters "
                f"{list(self.param_names)}, got {arr.tolist()}"
            )
        return arr

    # ----------------------------------------------------------------- disturbances
    def split_disturbances(self, matrix: np.ndarray, T: int) -> tuple[np.ndarray, np.ndarray]:
        """Split the paper's (d+p)T x K disturbance matrix (Sec. III.A).

        Rows are the state disturbances eta_1..eta_T first (p per step, time-major),
        then the observation disturbances eps_1..eps_T (d per step).  Returns
        ``eta`` (K, T, p) and ``eps`` (K, T, d).
        """
        p, d = self.state_dim, self.obs_dim
        matrix = np.asarray(matrix, dtype=float)
        if matrix.ndim != 2 or matrix.shape[0] != (p + d) * T:
            raise ValueError(
                f"disturbance matrix for model '{self.slug}' with T={T} must have "
                f"(d+p)T = {(p + d) * T} rows, got shape {matrix.shape}"
            )
        K = matrix.shape[1]
        eta = matrix[: p * T].T.reshape(K, T, p)
        eps = matrix[p * T :].T.reshape(K, T, d)
        return eta, eps

    def design_trajectories(
        self,
        omega: Mapping[str, float] | Sequence[float] | np.ndarray,
        x0: Sequence[float] | float | np.ndarray,
        matrix: np.ndarray,
        T: int,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Design states and observations x~(k), z~(k) for every column k (Sec. III.A)."""
        eta, eps = self.split_disturbances(matrix, T)
        omega_v = self.omega_array(omega)
        x0_v = np.atleast_1d(np.asarray(x0, dtype=float))
        return self.simulate(omega_v, x0_v, eta, eps)

    # ----------------------------------------------------------------- Stan contract
    def stan_data(self, z: np.ndarray, bounds: PriorBounds) -> dict:
        """Data dict for ``stan/<slug>.stan`` (same for PyStan and cmdstanpy).

        ``z`` is one observation trajectory of shape (T, d).  Bounds of the prior are passed
        per parameter as ``<name>_lower`` / ``<name>_upper``; infinite bounds are passed as
        +-inf (Stan treats infinite bounds as no bound).
        """
        z = np.asarray(z, dtype=float)
        data: dict = {"T": int(z.shape[0])}
        data["z"] = z[:, 0].tolist() if self.obs_dim == 1 else z.tolist()
        for i, name in enumerate(self.param_names):
            data[f"{name}_lower"] = float(bounds.lower[i])
            data[f"{name}_upper"] = float(bounds.upper[i])
        return data

    def __repr__(self) -> str:  # pragma: no cover - cosmetic
        return f"<model {self.slug}: {self.title}>"
