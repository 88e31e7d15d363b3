"""Glue of the Stan stage (Sec. III.C; rules in ``workflow/rules/stan.smk``): the compiled
program, NUTS for one batch of trajectories, and the scenario's gathered table and summary.

The checks that a batch table still matches its records are in :mod:`ssmobs.nuts.record_cache`.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

from .. import io
from ..log import Progress
from . import PathLike

if TYPE_CHECKING:
    import numpy as np

    from ..config.stage_inputs import GatherInputs, NutsBatchesInputs, NutsRecordsInputs
    from ..design.trajectories import Trajectories
    from ..nuts.batch import NutsBatch
    from ..nuts.convergence import ConvergenceSettings
    from ..stan_backends.base import SamplerSettings

logger = logging.getLogger("ssmobs")


def sampler_settings(stan_cfg: Mapping[str, Any], threads: int = 1) -> SamplerSettings:
    """The NUTS settings of config block ``stan``, or of a record's sampler settings
    (``threads``: parallel chain processes)."""
    from ..stan_backends.base import SamplerSettings

    return SamplerSettings(
        chains=stan_cfg["chains"],
        iter_warmup=stan_cfg["iter_warmup"],
        iter_sampling=stan_cfg["iter_sampling"],
        adapt_delta=stan_cfg["adapt_delta"],
        max_treedepth=stan_cfg["max_treedepth"],
        init_radius=float(stan_cfg.get("init_radius", 2.0)),
        workers=max(1, threads),
    )


def header_kwargs(header: Path | None) -> dict[str, Path]:
    """``user_header=header`` for a backend call, nothing without one (PyStan takes none)."""
    return {} if header is None else {"user_header": header}


def run_build_stan_model(
    model: str, backend: str, out: PathLike, gradients: str = "autodiff"
) -> dict:
    """Rule build_stan_model: write the model's program where it is generated
    (:func:`~ssmobs.nuts.stan_program.stan_program`, the one job that writes it), compile it
    once and write the backend's marker, which names the program and its C++ header
    (``program_file``, ``header_file``: what the NUTS batches run)."""
    from ..nuts.stan_program import stan_program
    from ..stan_backends import get_backend

    program, header = stan_program(model, gradients)
    marker = {
        **get_backend(backend).compile(program, **header_kwargs(header)),
        "program_file": str(program),
        "header_file": None if header is None else str(header),
    }
    io.write_json(out, marker)
    return marker


def nuts_batch(
    inputs: NutsRecordsInputs,
    traj: Trajectories,
    program: tuple[Path, Path | None],
    threads: int,
    convergence: ConvergenceSettings,
    init_theta: np.ndarray | None = None,
) -> NutsBatch:
    """The NUTS batch of a scenario (:class:`ssmobs.nuts.batch.NutsBatch`) from what
    determines its records (:class:`~ssmobs.config.stage_inputs.NutsRecordsInputs`): its
    design trajectories, true values, prior bounds, seeds and chains' start, the sampler
    settings on ``threads`` chain processes; ``program``: the Stan program and C++ header
    its build job compiled (:func:`~ssmobs.nuts.stan_program.built_program`);
    ``convergence``: the checks; ``init_theta``: the joint MAP of every k
    (``stan_init: joint_map``)."""
    from ..nuts.batch import NutsBatch

    model = traj.model
    if model.slug != inputs.model:
        raise ValueError(
            f"scenario {inputs.scenario}: model {inputs.model}, trajectories' model {model.slug}"
        )
    stan_file, header = program
    if (header is not None) != (inputs.gradients == "analytic"):  # a program of another key
        raise ValueError(
            f"scenario {inputs.scenario}: {inputs.gradients} gradients, but the program "
            f"{stan_file} was built {'with' if header else 'without'} a gradient header"
        )
    return NutsBatch(
        model=model,
        stan_file=stan_file,
        z=traj.z,
        x_true=traj.x,
        bounds=model.prior_bounds(traj.omega, inputs.prior_config),
        omega_true=traj.omega,
        x0_true=traj.x0,
        scenario=inputs.scenario,
        seed=inputs.seed,
        sampler=sampler_settings(dict(inputs.sampler), threads),
        convergence=convergence,
        init=inputs.stan_init,
        stan_seed=inputs.stan_seed,
        init_theta=init_theta,
        user_header=header,
    )


def run_sample_batch(inputs: NutsBatchesInputs, paths: Mapping[str, PathLike]) -> None:
    """Rule sample_nuts: NUTS, checks and marginal MAPs for one batch of trajectories, from
    its :class:`~ssmobs.config.stage_inputs.NutsBatchesInputs` alone; ``paths``: the output
    ``table``, whose file name names the batch (as in :data:`ssmobs.stage_table.STAGES`).
    Where the chains start at the joint MAP, ``inputs.record.joint_map`` is rule joint_map's
    ``theta_hat.nc``.  The Stan program is the one rule build_stan_model compiled, named by
    its marker: this job writes no program.

    Each trajectory's record is written on its own as soon as it is done; a rerun after an
    interruption reuses every valid record (see :func:`ssmobs.nuts.batch.run_trajectories`).
    """
    from ..design.trajectories import read_trajectories
    from ..nuts.batch import run_trajectories
    from ..nuts.convergence import ConvergenceSettings, apply_thresholds
    from ..nuts.record_cache import draws_path, record_path
    from ..nuts.record_format import records_to_frame
    from ..nuts.stan_program import built_program
    from ..stan_backends import get_backend

    record = inputs.record
    traj = read_trajectories(record.trajectories)
    backend_name, program, header = built_program(record.program)
    name = inputs.record.scenario
    if traj.K != inputs.K:
        raise ValueError(f"scenario {name}: K = {inputs.K}, trajectories K = {traj.K}")
    out = paths["table"]
    ks = list(inputs.batch_of(Path(out).name))
    records_dir, draws_dir = inputs.records, inputs.draws
    # the shared folders' files of this batch: no other job writes them
    io.sweep_temporaries(
        [record_path(records_dir, k) for k in ks] + [draws_path(draws_dir, k) for k in ks]
    )
    progress = Progress(f"NUTS {name} batch {Path(out).stem[5:]}", len(ks), logger)
    theta_hat = None if record.joint_map is None else _theta_hat(record.joint_map, traj.K)
    settings = ConvergenceSettings(**inputs.convergence_config)
    records = run_trajectories(
        nuts_batch(record, traj, (program, header), inputs.threads, settings, theta_hat),
        get_backend(backend_name),
        ks,
        records_dir=records_dir,
        keep_draws_for=set(inputs.keep_draws) & set(ks),
        draws_dir=draws_dir,
        progress=progress,
    )
    frame = records_to_frame(records, traj.model, traj.T)
    io.write_parquet(out, apply_thresholds(frame, settings))


def _theta_hat(path: PathLike, K: int) -> Any:
    """(K, n_theta) joint MAP of every trajectory from rule joint_map's ``theta_hat.nc``."""
    import numpy as np

    ds = io.read_netcdf(path, required_vars=["theta_hat"])
    theta = np.asarray(ds["theta_hat"], dtype=float)
    if theta.shape[0] != K or ds["k"].tolist() != list(range(K)):
        raise io.CorruptFileError(f"{path}: joint MAP of {theta.shape[0]} trajectories, K = {K}")
    return theta


def run_gather_nuts(inputs: GatherInputs, paths: Mapping[str, PathLike]) -> dict:
    """Rule gather_nuts: one table of all trajectories and the scenario's Stan summary, from
    its :class:`~ssmobs.config.stage_inputs.GatherInputs` alone; ``paths``: the outputs
    ``table`` and ``summary``, as in :data:`ssmobs.stage_table.STAGES`.

    The table marks in ``off_support`` every marginal MAP or quantile off its prior support
    or from draws that ran off (:func:`ssmobs.nuts.off_support.mark_off_support`; the summary
    counts those rows in ``n_off_support``).

    The batch tables hold the configured convergence checks applied to the records'
    diagnostics (:func:`ssmobs.nuts.convergence.apply_thresholds`), so other thresholds rebuild
    the tables without new sampling; each is checked against its records first
    (:func:`ssmobs.nuts.record_cache.check_batch_records`)."""
    import pandas as pd

    from ..design.trajectories import read_trajectories
    from ..nuts.off_support import mark_off_support
    from ..nuts.record_cache import check_batch_records
    from ..nuts.stan_metrics import stan_summary

    traj = read_trajectories(inputs.trajectories)
    name, convergence = inputs.scenario, inputs.convergence_config
    batch_tables = inputs.batches
    frames = [io.read_parquet(p, required_columns=["k", "converged"]) for p in batch_tables]
    for path, batch_frame in zip(batch_tables, frames):
        check_batch_records(path, batch_frame, traj.model, traj.T, inputs.records, convergence)
    frame = pd.concat(frames, ignore_index=True)
    frame = frame.sort_values("k", kind="stable").reset_index(drop=True)
    expected = inputs.stan_trajectories
    if frame["k"].tolist() != list(expected):
        raise io.CorruptFileError(
            f"batch tables of scenario {name} do not cover "
            f"k = {expected.start}, {expected.start + expected.step}, ..., "
            f"{expected[-1] if len(expected) else '-'} exactly once"
        )
    # every marginal MAP or quantile off the prior support or run off, marked in the file
    bounds = traj.model.prior_bounds(traj.omega, inputs.prior_config)
    frame = mark_off_support(frame, traj.model, bounds, traj.T)
    info = stan_summary(frame, traj.model, traj.omega, traj.x0, traj.x)
    info["n_off_support"] = int((frame["off_support"] != "").sum())
    info.update(scenario=name, model=traj.model.slug, T=traj.T, stan_init=inputs.stan_init)
    logger.info("scenario %s: |K^Stan| = %s of %d", name, info["n_stan"], len(frame))
    io.write_parquet(paths["table"], frame)
    io.write_json(paths["summary"], info)
    return info
