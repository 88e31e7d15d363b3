"""Per-scenario properties of the marginal MAP estimator over K^Stan (Sec. III.C, Sec. IV).

Given the per-trajectory table of :func:`ssmobs.nuts.record_format.records_to_frame`,
:func:`stan_summary` returns

* ``n_stan`` = |K^Stan| (trajectories that passed every check), ``K`` (rows of the table)
  and ``ratio`` = |K^Stan| / K;
* for every component of Omega and x0 (``<name>`` as in ``model.theta_names``):
  ``<name>_true``, ``<name>_mean`` (empirical mean of the marginal MAP over K^Stan),
  ``<name>_var`` (empirical variance, ddof = 1, as in Table II), ``<name>_bias`` (mean -
  true), ``<name>_mse`` (mean squared error about the true value) and ``<name>_cover90``
  (share of k in K^Stan with q5 < true < q95, strict as the paper's Cover90);
* for the states, with truth the design state x~_t^(k) of each k:
  ``x_cover90_mean`` = (1/T) sum_t Cover90(x_t), ``x_abs_bias_mean`` = (1/T) sum_t
  |Bias(x_t)| and ``x_mse_mean`` = (1/T) sum_t MSE(x_t) (Table III).  For p > 1 these are
  averaged over t and the state components; ``x{i}_cover90_mean`` etc. give each
  component i = 1..p separately.

With |K^Stan| = 0 every estimate is NaN (``ratio`` is 0); with |K^Stan| = 1 the variances
are NaN.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np

from ..estimator_moments import moment_entries, stat_key

if TYPE_CHECKING:
    from ..models.base import StateSpaceModel


def _col(frame: Any, name: str) -> np.ndarray:
    if name not in frame.columns:
        raise KeyError(f"the per-trajectory table has no column '{name}'")
    return frame[name].to_numpy(dtype=float)


def _mean(v: np.ndarray) -> float:
    return float(np.mean(v)) if v.size else math.nan


def stan_summary(
    frame: Any,
    model: StateSpaceModel,
    omega_true: np.ndarray,
    x0_true: np.ndarray,
    x_true: np.ndarray,
) -> dict[str, Any]:
    """|K^Stan| and the properties of the marginal MAP estimator over K^Stan.

    Parameters
    ----------
    frame : per-k table (:func:`ssmobs.nuts.record_format.records_to_frame`): columns ``k``,
        ``converged`` and ``<name>_map``/``_q5``/``_q95`` for every Theta component.
    model : the state space model (for parameter and Theta names).
    omega_true, x0_true : true Omega (array in ``model.param_names`` order) and x0 (array
        of p values), e.g. a :class:`~ssmobs.config.scenario.Scenario`'s.
    x_true : (K, T, p) design states; row ``k`` of the table is compared with ``x_true[k]``.

    Returns
    -------
    A flat dict of scalars (keys in the module docstring).
    """
    x_true = np.asarray(x_true, dtype=float)
    if x_true.ndim == 2:
        x_true = x_true[:, :, None]
    _, T, p = x_true.shape
    if p != model.state_dim:
        raise ValueError(
            f"x_true has {p} state components, model '{model.slug}' has {model.state_dim}"
        )
    names = model.theta_names(T)
    m = model.n_params
    omega = np.atleast_1d(np.asarray(omega_true, dtype=float)).ravel()
    x0 = np.atleast_1d(np.asarray(x0_true, dtype=float)).ravel()
    if omega.size != m or x0.size != p:
        raise ValueError(
            f"need {m} true parameter(s) and {p} x0 component(s), got "
            f"{omega.tolist()} and {x0.tolist()}"
        )

    conv = frame["converged"].to_numpy(dtype=bool)
    ks = frame["k"].to_numpy(dtype=np.int64)[conv]
    K = int(len(frame))
    n_stan = int(conv.sum())
    out: dict[str, Any] = {"K": K, "n_stan": n_stan, "ratio": (n_stan / K) if K else math.nan}

    truths = np.concatenate([omega, x0])
    for name, truth in zip(names[: m + p], truths):
        est = _col(frame, f"{name}_map")[conv]
        q5 = _col(frame, f"{name}_q5")[conv]
        q95 = _col(frame, f"{name}_q95")[conv]
        out[stat_key(name, "true")] = float(truth)
        out.update(moment_entries(name, est, truth))
        out[stat_key(name, "cover90")] = _mean(((q5 < truth) & (truth < q95)).astype(float))

    # states x_1..x_T: names[m + p:] are time-major (t = 1..T, component i = 1..p)
    state_names = names[m + p :]
    est = np.stack([_col(frame, f"{n}_map")[conv] for n in state_names], axis=1)
    q5 = np.stack([_col(frame, f"{n}_q5")[conv] for n in state_names], axis=1)
    q95 = np.stack([_col(frame, f"{n}_q95")[conv] for n in state_names], axis=1)
    if n_stan and ks.max() >= x_true.shape[0]:
        raise IndexError(
            f"table has trajectory k={int(ks.max())} but x_true has only {x_true.shape[0]} rows"
        )
    truth = x_true[ks].reshape(n_stan, T * p)  # (|K^Stan|, T*p), same time-major order
    if n_stan:
        bias_t = (est - truth).mean(axis=0)  # Bias(x_{t,i}), (T*p,)
        mse_t = ((est - truth) ** 2).mean(axis=0)  # MSE(x_{t,i})
        cover_t = ((q5 < truth) & (truth < q95)).mean(axis=0)  # Cover90(x_{t,i})
    else:
        bias_t = mse_t = cover_t = np.full(T * p, np.nan)
    out["x_cover90_mean"] = float(np.mean(cover_t))
    out["x_abs_bias_mean"] = float(np.mean(np.abs(bias_t)))
    out["x_mse_mean"] = float(np.mean(mse_t))
    if p > 1:
        for i in range(p):
            sel = slice(i, None, p)
            out[f"x{i + 1}_cover90_mean"] = float(np.mean(cover_t[sel]))
            out[f"x{i + 1}_abs_bias_mean"] = float(np.mean(np.abs(bias_t[sel])))
            out[f"x{i + 1}_mse_mean"] = float(np.mean(mse_t[sel]))
    return out
