"""One trajectory through rule ``sample_nuts``'s per-trajectory code on either gradient path
(issue 49), measured: shared by ``bench_gradients_profile.py`` and ``bench_paper_cost.py``."""

from __future__ import annotations

import resource
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

#: the two values of ``stan.gradients``
PATHS = ("autodiff", "analytic")


def cpu_seconds() -> float:
    """CPU seconds of this process and its waited-for children (the chain workers)."""
    own = resource.getrusage(resource.RUSAGE_SELF)
    kids = resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def simulate(sc: Any, n: int) -> tuple[np.ndarray, np.ndarray]:
    """(x, z) of ``n`` trajectories of scenario ``sc`` from random disturbances (numpy seed
    1, the same for both paths and every script)."""
    model = sc.model
    rng = np.random.default_rng(1)
    eta = rng.standard_normal((n, sc.T, model.state_dim))
    eps = rng.standard_normal((n, sc.T, model.obs_dim))
    return model.simulate(sc.omega, sc.x0, eta, eps)


def compiled_programs(native: Any, slug: str) -> dict[str, tuple[Any, Any]]:
    """Path -> (Stan program, user header or None) of model ``slug``, compiled (cached)
    before any clock starts."""
    from ssmobs.nuts.stan_program import stan_program

    programs = {g: stan_program(slug, g) for g in PATHS}
    for prog, header in programs.values():
        native.compile(prog, **({} if header is None else {"user_header": header}))
    return programs


@dataclass(frozen=True)
class Measured:
    """One trajectory on one path: the whole per-trajectory part of a ``sample_nuts`` job."""

    cpu_s: float
    wall_s: float
    driver_cpu_s: float
    converged: bool
    record: dict


def run_one(
    native: Any,
    sc: Any,
    config: dict,
    program: tuple[Any, Any],
    xz: tuple[np.ndarray, np.ndarray],
    k: int,
    records_dir: Path,
) -> Measured:
    """Trajectory ``k`` of ``xz`` through :func:`ssmobs.nuts.batch.run_trajectories` with
    the scenario's sampler settings from ``config`` (a validated config)."""
    from ssmobs.nuts.batch import NutsBatch, run_trajectories
    from ssmobs.nuts.convergence import ConvergenceSettings
    from ssmobs.stages.stan import sampler_settings

    prog, header = program
    x, z = xz
    batch = NutsBatch(
        model=sc.model,
        stan_file=prog,
        z=z,
        x_true=x,
        bounds=sc.prior_bounds(),
        omega_true=sc.omega,
        x0_true=sc.x0,
        scenario=sc.name,
        seed=sc.seed,
        sampler=sampler_settings(sc.stan_config(config["stan"]), 1),
        convergence=ConvergenceSettings(**config["convergence"]),
        init=sc.stan_init,
        stan_seed=sc.stan_seed,
        user_header=header,
    )
    c0, w0 = cpu_seconds(), time.perf_counter()
    (rec,) = run_trajectories(batch, native, [k], records_dir=records_dir)
    return Measured(
        cpu_s=cpu_seconds() - c0,
        wall_s=time.perf_counter() - w0,
        # absent when the sampler raised (the record says so)
        driver_cpu_s=float(rec["timings"].get("backend", {}).get("sample_cpu", "nan")),
        converged=bool(rec["converged"]),
        record=rec,
    )
