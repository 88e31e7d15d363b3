"""The NUTS stage of Sec. III.C: per design trajectory k, sample, check, summarise.

:func:`run_trajectories` is the loop one batch job runs: for every k of its batch it

1. skips k if ``records_dir/k{k:05d}.json`` exists and validates (same key: scenario, k,
   seed, Stan program hash, settings hash, data hash; see :mod:`ssmobs.nuts.record_cache`), else
2. samples pi(Theta | z~(k)) with the backend, seed ``seeds.int_seed(seed, "nuts",
   scenario, k)``, random or true initial values,
3. checks convergence (:func:`ssmobs.nuts.convergence.check_convergence`),
4. computes the marginal MAP and 5 %/95 % quantiles of every Theta component
   (:func:`ssmobs.nuts.marginal_map.marginal_summary`, Eq. (11), (12)),
5. writes the record atomically, and the draws as NetCDF (ArviZ) for k in ``keep_draws_for``.

A failure of the sampler on one trajectory (:class:`SamplingError`, data the model
rejects) or of our summaries (a KDE on zero-spread draws, anything in the checks) becomes a
record with ``converged: false`` and the reason; the loop goes on.  Any other error of the
backend (:class:`~ssmobs.stan_backends.base.BackendError`: a missing library, a killed
driver) fails the job without a record, so a broken installation never yields a finished
run with |K^Stan| = 0.  Only the per-trajectory records (and draws where asked) are
written, so an interrupted batch resumes where it stopped.

The record format and the table built from records: :mod:`ssmobs.nuts.record_format`.
"""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from .. import io
from ..log import Progress
from ..stan_backends.base import Draws, SamplerSettings, SamplingError
from .convergence import ConvergenceSettings, check_convergence, to_inference_data
from .marginal_map import KDEError, marginal_summary
from .record_cache import (
    RECORD_VERSION,
    backend_identity,
    draws_path,
    load_record,
    program_hash,
    record_key,
    record_path,
    settings_hash,
    write_record,
)

if TYPE_CHECKING:
    from ..models.base import StateSpaceModel
    from ..stan_backends.base import StanBackend

LOG = logging.getLogger("ssmobs.nuts")

INIT_MODES = ("random", "true", "joint_map")


# --------------------------------------------------------------------------- the batch
@dataclass(frozen=True)
class NutsBatch:
    """Everything that determines the NUTS records of one scenario's trajectories (Sec.
    III.C), built once from the scenario (:func:`ssmobs.stages.stan.nuts_batch`) and passed
    whole to :func:`run_trajectories`; where the records go is no part of it.

    model : a :class:`~ssmobs.models.base.StateSpaceModel`.
    stan_file : the model's Stan program (its text hash is part of every record's key).
    z : (K, T, d) design observations; ``z[k]`` is trajectory k (a (K, T) array for d = 1).
    x_true : (K, T, p) design states (used for the key and, with ``init="true"``, inits).
    bounds : the prior's :class:`~ssmobs.models.base.PriorBounds`.
    omega_true, x0_true : true parameters (array in ``model.param_names`` order) and
        initial state (array of p values), e.g. a :class:`~ssmobs.config.scenario.Scenario`'s.
    scenario, seed : scenario name and seed; Stan's seed is
        ``seeds.int_seed(seed, "nuts", scenario, k)``, or ``stan_seed`` for every k when
        given (as a loop calling Stan with one fixed seed would).
    sampler, convergence : NUTS settings and thresholds (defaults: the paper's / Stan's).
    init : ``"random"`` (Stan's uniform(-r, r) on the unconstrained scale with r =
        ``sampler.init_radius``, 2 by default: the paper's), ``"true"`` (all chains at the
        true Omega, x0 and design states) or ``"joint_map"`` (all chains at trajectory k's
        joint MAP, row k of ``init_theta``, where :func:`joint_map_point` gives one, else
        random; the point is in the key).
    user_header : the C++ header defining the program's external functions (the analytic
        gradients of :mod:`ssmobs.nuts.analytic_gradients`); keyed with the program.
    """

    model: StateSpaceModel
    stan_file: str | Path
    z: np.ndarray
    x_true: np.ndarray
    bounds: Any
    omega_true: np.ndarray
    x0_true: np.ndarray
    scenario: str
    seed: int
    sampler: SamplerSettings = field(default_factory=SamplerSettings)
    convergence: ConvergenceSettings = field(default_factory=ConvergenceSettings)
    init: str = "random"
    stan_seed: int | None = None
    init_theta: np.ndarray | None = None
    user_header: str | Path | None = None

    def __post_init__(self) -> None:
        """Checks the values and stores them in the shapes the loop uses: ``z`` and
        ``x_true`` as (K, T, .) floats, Omega and x0 as float vectors, the program as text."""
        if self.init not in INIT_MODES:
            raise ValueError(f"init must be one of {INIT_MODES}, got {self.init!r}")
        if (self.init == "joint_map") != (self.init_theta is not None):
            raise ValueError(
                'init_theta (the joint MAP of every k) goes with init="joint_map" only'
            )
        z = np.asarray(self.z, dtype=float)
        x_true = np.asarray(self.x_true, dtype=float)
        if z.ndim == 2:
            z = z[:, :, None]
        if x_true.ndim == 2:
            x_true = x_true[:, :, None]
        if z.shape[:2] != x_true.shape[:2]:
            raise ValueError(f"z {z.shape} and x_true {x_true.shape} disagree in (K, T)")
        omega_true = np.asarray(self.omega_true, dtype=float)
        x0_true = np.atleast_1d(np.asarray(self.x0_true, dtype=float))
        model = self.model
        if omega_true.shape != (model.n_params,) or x0_true.shape != (model.state_dim,):
            raise ValueError(
                f"need Omega as {model.n_params} value(s) in the order "
                f"{list(model.param_names)} and x0 as {model.state_dim} value(s), got "
                f"{omega_true.tolist()} and {x0_true.tolist()}"
            )
        for name, value in (
            ("z", z),
            ("x_true", x_true),
            ("omega_true", omega_true),
            ("x0_true", x0_true),
            ("stan_file", str(self.stan_file)),
        ):
            object.__setattr__(self, name, value)

    @property
    def T(self) -> int:
        """The trajectories' length."""
        return int(self.z.shape[1])

    @property
    def header(self) -> dict[str, Path]:
        """The keyword arguments of the backend's compile and sample for the header."""
        return {} if self.user_header is None else {"user_header": Path(self.user_header)}


# --------------------------------------------------------------------------- one trajectory
def _inits(
    model: StateSpaceModel,
    omega_true: np.ndarray,
    x0_true: np.ndarray,
    x_k: np.ndarray,
    chains: int,
) -> list[dict[str, Any]]:
    """Initial values at the true (Omega, x0) and the design states x~(k), one dict per chain."""
    init: dict[str, Any] = dict(zip(model.param_names, _floats(omega_true)))
    x0 = _floats(np.atleast_1d(x0_true))
    x = np.asarray(x_k, dtype=float)
    if model.state_dim == 1:
        init["x0"] = x0[0]
        init["x"] = x.reshape(-1).tolist()
    else:
        init["x0"] = x0
        init["x"] = x.reshape(x.shape[0], model.state_dim).tolist()
    return [dict(init) for _ in range(chains)]


def joint_map_point(
    model: StateSpaceModel, theta_hat: np.ndarray, bounds: Any, T: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """(Omega, x0, x) of a trajectory's joint MAP ``theta_hat`` (``model.theta_names(T)``
    order) as Stan inits, or None where it is not finite or Omega is not strictly inside
    the prior's support (a joint MAP that failed its checks may sit on a bound)."""
    theta = np.asarray(theta_hat, dtype=float)
    m, p = model.n_params, model.state_dim
    if theta.shape != (m + p + T * p,) or not np.isfinite(theta).all():
        return None
    omega = theta[:m]
    lower, upper = np.asarray(bounds.lower, float), np.asarray(bounds.upper, float)
    if not ((omega > lower) & (omega < upper)).all():
        return None
    return omega, theta[m : m + p], theta[m + p :].reshape(T, p)


def _floats(values: np.ndarray) -> list[float]:
    return [float(v) for v in np.asarray(values, dtype=float)]


def _one_trajectory(
    batch: NutsBatch,
    backend: StanBackend,
    k: int,
    key: dict[str, Any],
    keep_draws: Path | None,
    init_point: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
) -> dict[str, Any]:
    model, sampler, init = batch.model, batch.sampler, batch.init
    z_k, x_k = batch.z[k], batch.x_true[k]
    T = batch.T
    names = model.theta_names(T)
    t0, c0 = time.perf_counter(), time.process_time()
    sample_cpu = 0.0
    timings: dict[str, Any] = {
        "sample_call": 0.0,
        "backend": {},
        "prepare": 0.0,
        "diagnostics": 0.0,
        "marginal": 0.0,
        "keep_draws": 0.0,
    }
    rec: dict[str, Any] = {
        "record_version": RECORD_VERSION,
        "key": key,
        "k": int(k),
        "scenario": batch.scenario,
        "model": model.slug,
        "T": T,
        "status": "ok",
        "converged": False,
        "failed_checks": [],
        "reason": None,
        "diagnostics": None,
        "theta_names": names,
        "map": None,
        "q5": None,
        "q95": None,
        # "joint_map" falls back to Stan's random inits where the joint MAP gives no point
        "init": init if init != "joint_map" or init_point is not None else "joint_map: random",
        "backend": getattr(backend, "name", type(backend).__name__),
    }
    reasons: list[str] = []
    draws: Draws | None = None
    try:
        data = model.stan_data(np.asarray(z_k, dtype=float), batch.bounds)
        inits = None
        if init == "true":
            inits = _inits(model, batch.omega_true, batch.x0_true, x_k, sampler.chains)
        elif init_point is not None:  # init "joint_map": this trajectory's joint MAP
            inits = _inits(model, *init_point, sampler.chains)
        t1, c1 = time.perf_counter(), time.process_time()
        timings["prepare"] = t1 - t0
        try:
            draws = backend.sample(
                str(batch.stan_file), data, key["stan_seed"], sampler, inits, **batch.header
            )
        finally:
            timings["sample_call"] = time.perf_counter() - t1
            sample_cpu = time.process_time() - c1
    except SamplingError as err:
        rec.update(
            status="error", failed_checks=["sampling_error"], reason=f"sampling error: {err}"
        )
        LOG.warning("k=%d: %s", k, rec["reason"])
    except ValueError as err:  # the model rejected these data (e.g. a reject() statement)
        rec.update(
            status="error",
            failed_checks=["exception"],
            reason=f"exception during sampling: {type(err).__name__}: {err}",
        )
        LOG.warning("k=%d: %s", k, rec["reason"], exc_info=True)
    # anything else (BackendError: a broken installation, a killed driver; bugs) is not a
    # property of this trajectory: it fails the job and no record is written

    if draws is not None:
        timings["backend"] = {kk: float(v) for kk, v in (draws.timings or {}).items()}
        failed: list[str] = []
        t2 = time.perf_counter()
        try:
            diag = check_convergence(draws, batch.convergence, max_treedepth=sampler.max_treedepth)
            rec["diagnostics"] = diag
            failed.extend(diag["failed_checks"])
            reasons.extend(diag["messages"])
        except Exception as err:  # noqa: BLE001
            failed.append("exception")
            reasons.append(f"convergence diagnostics failed: {type(err).__name__}: {err}")
            LOG.warning("k=%d: %s", k, reasons[-1], exc_info=True)
        t3 = time.perf_counter()
        timings["diagnostics"] = t3 - t2
        try:
            summ = marginal_summary(draws, model, T)
            rec["map"] = _floats(summ["map"])
            rec["q5"] = _floats(summ["q5"])
            rec["q95"] = _floats(summ["q95"])
        except KDEError as err:
            failed.append("kde")
            reasons.append(f"kde: {err}")
        except Exception as err:  # noqa: BLE001
            failed.append("exception")
            reasons.append(f"marginal summary failed: {type(err).__name__}: {err}")
            LOG.warning("k=%d: %s", k, reasons[-1], exc_info=True)
        t4 = time.perf_counter()
        timings["marginal"] = t4 - t3
        if keep_draws is not None:
            try:
                _write_draws(keep_draws, draws, rec)
                rec["draws_sha256"] = io.file_sha256(keep_draws)
            except Exception as err:  # noqa: BLE001 - a lost copy of the draws is no failure
                LOG.warning("k=%d: could not keep draws at %s: %s", k, keep_draws, err)
            timings["keep_draws"] = time.perf_counter() - t4
        seen: list[str] = []
        for c in failed:
            if c not in seen:
                seen.append(c)
        rec["failed_checks"] = seen
        rec["converged"] = not seen and rec["map"] is not None
        rec["reason"] = None if rec["converged"] else "; ".join(reasons) or "not converged"
    total = time.perf_counter() - t0
    timings["overhead"] = total - timings["sample_call"]
    timings["overhead_cpu"] = time.process_time() - c0 - sample_cpu
    rec["timings"] = timings
    return rec


def _draws_intact(path: Path, rec: dict[str, Any]) -> bool:
    """The kept draws file exists and matches the checksum its record holds (a record
    without one: damaged)."""
    if not path.exists():
        return False
    expected = rec.get("draws_sha256")
    return expected is not None and io.file_sha256(path) == expected


def _write_draws(path: Path, draws: Draws, rec: dict[str, Any]) -> None:
    idata = to_inference_data(draws)
    idata.posterior.attrs.update(
        {
            "scenario": rec["scenario"],
            "k": rec["k"],
            "stan_seed": rec["key"]["stan_seed"],
            "program_hash": rec["key"]["program_hash"],
        }
    )
    for group in idata.subtree:  # ArviZ's creation time: the file's bytes are its draws'
        group.attrs.pop("created_at", None)
    with io.atomic_path(path, suffix=".nc") as tmp:
        idata.to_netcdf(str(tmp), engine="h5netcdf")


# --------------------------------------------------------------------------- the loop
def run_trajectories(
    batch: NutsBatch,
    backend: StanBackend,
    ks: Sequence[int],
    records_dir: str | os.PathLike = ".",
    keep_draws_for: Iterable[int] = (),
    draws_dir: str | os.PathLike | None = None,
    progress: Progress | None = None,
    retry_errors: bool = False,
) -> list[dict[str, Any]]:
    """Sample, check and summarise the design trajectories ``ks`` of one scenario.

    Parameters
    ----------
    batch : what determines the records (:class:`NutsBatch`: the model, its program, the
        design trajectories, the true values, the seeds and the settings).
    backend : a :class:`~ssmobs.stan_backends.base.StanBackend` (``compile``/``sample``).
    ks : trajectory indices (0-based rows of ``batch.z``) to process, in order.
    records_dir : where ``k{k:05d}.json`` records go.
    keep_draws_for : k whose draws are written to ``draws_dir/k{k:05d}.nc`` (ArviZ).
    progress : a :class:`~ssmobs.log.Progress` updated once per k of ``ks`` (skipped ones
        included); if None, one is made for the trajectories that need sampling.
    retry_errors : recompute stored records whose status is "error" (e.g. after fixing
        the cause of an exception); by default every valid record is reused.

    Returns
    -------
    The records (dicts, format in the module docstring), in the order of ``ks``.
    """
    model, z, x_true, bounds, T = batch.model, batch.z, batch.x_true, batch.bounds, batch.T
    keep = {int(k) for k in keep_draws_for}
    if keep and draws_dir is None:
        raise ValueError("keep_draws_for needs draws_dir")
    stan_file = str(batch.stan_file)
    prog = program_hash(stan_file, batch.user_header)
    set_hash = settings_hash(
        model,
        T,
        batch.sampler,
        batch.convergence,
        batch.init,
        bounds,
        batch.omega_true,
        batch.x0_true,
    )
    n_theta = len(model.theta_names(T))
    ident = backend_identity(backend)
    scenario, init_theta = batch.scenario, batch.init_theta

    records: dict[int, dict[str, Any]] = {}
    todo: list[tuple[int, dict[str, Any]]] = []
    points: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray] | None] = {}
    for k in ks:
        k = int(k)
        if not 0 <= k < z.shape[0]:
            raise IndexError(f"trajectory k={k} outside 0..{z.shape[0] - 1}")
        points[k] = None if init_theta is None else joint_map_point(model, init_theta[k], bounds, T)
        key = record_key(
            scenario,
            k,
            batch.seed,
            prog,
            set_hash,
            z[k],
            x_true[k],
            ident,
            stan_seed=batch.stan_seed,
            init_point=points[k],
        )
        rec = load_record(record_path(records_dir, k), key, n_theta)
        if rec is not None and retry_errors and rec["status"] == "error":
            rec = None
        if (
            rec is not None
            and k in keep
            and draws_dir is not None  # checked above: keep needs draws_dir
            and not _draws_intact(draws_path(draws_dir, k), rec)
        ):
            LOG.info(
                "recomputing k=%d: its draws are to be kept but %s is missing or damaged",
                k,
                draws_path(draws_dir, k),
            )
            rec = None
        if rec is None:
            todo.append((k, key))
        else:
            records[k] = rec
    stale = sum(record_path(records_dir, k).exists() for k, _ in todo)
    LOG.info(
        "%s: %d trajectories to sample, %d records reused, %d stale or damaged records recomputed",
        scenario,
        len(todo),
        len(records),
        stale,
    )
    if records and progress is not None:
        progress.update(len(records))
    own_progress = progress is None
    if own_progress:
        progress = Progress(f"{scenario} NUTS", total=max(len(todo), 1), logger=LOG)
    assert progress is not None  # given, or made just above
    if todo:
        backend.compile(stan_file, **batch.header)
    for k, key in todo:
        rec = _one_trajectory(
            batch,
            backend,
            k,
            key,
            draws_path(draws_dir, k) if k in keep and draws_dir is not None else None,
            points[k],
        )
        t_w = time.perf_counter()
        write_record(record_path(records_dir, k), rec)
        LOG.debug(
            "k=%d: converged=%s %s (sample %.2f s, overhead %.3f s, write %.3f s)",
            k,
            rec["converged"],
            rec["reason"] or "",
            rec["timings"]["sample_call"],
            rec["timings"]["overhead"],
            time.perf_counter() - t_w,
        )
        records[k] = rec
        progress.update()
    return [records[int(k)] for k in ks]
