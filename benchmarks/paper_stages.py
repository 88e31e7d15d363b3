"""The measured pieces of ``bench_paper_stages.py`` (issue 63, item 3): the paper profile's
design sets, each stage of one design trajectory, one point of a choice-of-K grid and one
compile, each timed in CPU seconds of this process and its children
(:func:`nuts_paths.cpu_seconds`)."""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from nuts_paths import cpu_seconds, run_one


@dataclass(frozen=True)
class DesignSet:
    """One design disturbance set as the workflow keys it: (q, K, method, seed)."""

    q: int
    K: int
    method: str
    seed: int

    @property
    def name(self) -> str:
        return f"q{self.q}_K{self.K}_{self.method}_seed{self.seed}"


def scenario_set(sc: Any) -> DesignSet:
    """The design set of scenario ``sc`` at its K (rule design_trajectories' input)."""
    return DesignSet(sc.disturbance_dim, sc.K, sc.method, sc.seed)


def build_set(ds: DesignSet, design_cfg: dict, out: Path) -> float:
    """Build ``ds`` with the workflow's function into ``out``; its CPU seconds."""
    from ssmobs.design.disturbance_sets import write_disturbance_set

    c0 = cpu_seconds()
    write_disturbance_set(ds.q, ds.K, ds.method, ds.seed, design_cfg, out)
    return cpu_seconds() - c0


def trajectories(sc: Any, path: Path) -> Any:
    """The scenario's design trajectories from its set at ``path`` (as the workflow makes
    them: :func:`ssmobs.design.trajectories.make_trajectories`)."""
    from ssmobs import io
    from ssmobs.design.trajectories import make_trajectories

    matrix, attrs = io.read_disturbances(path, q=sc.disturbance_dim, K=sc.K)
    return make_trajectories(sc, matrix, provenance=attrs)


def spread_columns(K: int, n: int) -> list[int]:
    """The first ``n`` columns k_j = floor(K * phi_2(j)) of a set of K, phi_2 the base-2
    radical inverse (0, 1/2, 1/4, 3/4, 1/8, ...): every prefix is spread over the set."""
    cols = []
    for j in range(n):
        x, f, i = 0.0, 0.5, j
        while i:
            x += f * (i & 1)
            i >>= 1
            f /= 2
        cols.append(int(K * x))
    return cols


def joint_map_cpu(sc: Any, config: dict, traj: Any) -> float:
    """CPU seconds of rule joint_map's work on every trajectory of ``traj`` (the
    scenario's starts: one, or the joint_map block's n_starts)."""
    from ssmobs.joint_map.driver import joint_map_of
    from ssmobs.joint_map.multi_start_summary import multi_start_of
    from ssmobs.joint_map.problem import JointMapProblem

    settings = sc.joint_map_config(config["joint_map"])
    run = multi_start_of if int(settings.get("n_starts", 1)) > 1 else joint_map_of
    c0 = cpu_seconds()
    run(JointMapProblem.of_trajectories(traj, sc.prior, settings))
    return cpu_seconds() - c0


def exact_cpu(sc: Any, config: dict, traj: Any) -> float:
    """CPU seconds of rule exact_marginal's work on every trajectory of ``traj``, at the
    profile's ``exact_marginal`` settings."""
    from ssmobs.exact.marginal import exact_marginal
    from ssmobs.exact.settings import ExactSettings

    bounds = traj.model.prior_bounds(traj.omega, sc.prior)
    settings = ExactSettings.from_mapping(config["exact_marginal"])
    c0 = cpu_seconds()
    exact_marginal(traj.model, traj.z, bounds, settings)
    return cpu_seconds() - c0


def nuts_cpu(
    native: Any, sc: Any, config: dict, program: Any, traj: Any, k: int
) -> tuple[float, bool]:
    """CPU seconds and convergence of rule sample_nuts' per-trajectory work on ``k``."""
    with tempfile.TemporaryDirectory() as tmp:
        one = run_one(native, sc, config, program, (traj.x, traj.z), k, Path(tmp))
    return one.cpu_s, one.converged


def grid_point_cpu(
    sc: Any, config: dict, K: int, method: str, seed: int, sets: str, work: Path
) -> tuple[float, float]:
    """One point of rule k_selection_grid, measured: (CPU seconds of its design set, of its
    joint MAP over the set's K trajectories from one start), as the rule computes it."""
    from ssmobs import io
    from ssmobs.design.trajectories import make_trajectories
    from ssmobs.joint_map.driver import joint_map_of
    from ssmobs.joint_map.problem import JointMapProblem
    from ssmobs.k_selection import set_seed

    s = set_seed(seed, K, sets)
    ds = DesignSet(sc.disturbance_dim, K, method, s)
    path = work / f"grid_{ds.name}.nc"
    design = build_set(ds, config["design"], path)
    matrix, attrs = io.read_disturbances(path, q=ds.q, K=K)
    pt = sc.replace(K=K, method=method, seed=s)
    traj = make_trajectories(pt, matrix, provenance=attrs)
    settings = pt.joint_map_config(config["joint_map"], single_start=True)
    c0 = cpu_seconds()
    joint_map_of(JointMapProblem.of_trajectories(traj, pt.prior, settings))
    jm = cpu_seconds() - c0
    path.unlink()
    return design, jm


def compile_cpu(slug: str, gradients: str) -> tuple[float, float]:
    """(CPU seconds, wall seconds) of compiling model ``slug``'s program on ``gradients``
    into an empty program cache (a child process with its own ``SSMOBS_CACHE``)."""
    code = (
        "from ssmobs.nuts.stan_program import stan_program\n"
        "from ssmobs.stan_backends.native import NativeBackend\n"
        f"prog, header = stan_program({slug!r}, {gradients!r})\n"
        "NativeBackend().compile(prog, **({} if header is None else {'user_header': header}))\n"
    )
    with tempfile.TemporaryDirectory() as cache:
        env = {**os.environ, "SSMOBS_CACHE": cache}
        c0, w0 = cpu_seconds(), time.perf_counter()
        subprocess.run([sys.executable, "-c", code], env=env, check=True)
        return cpu_seconds() - c0, time.perf_counter() - w0


def loglog_interp(points: list[tuple[float, float]], K: np.ndarray) -> np.ndarray:
    """t(K) piecewise linear in (log K, log t) through the measured ``points`` (K, t), the
    end segments extended; one point: t proportional to K."""
    pts = sorted({int(k): float(t) for k, t in points}.items())
    k = np.log([p[0] for p in pts])
    t = np.log([max(p[1], 1e-6) for p in pts])
    x = np.log(np.asarray(K, dtype=float))
    if len(pts) == 1:
        return np.exp(t[0] + x - k[0])
    i = np.clip(np.searchsorted(k, x) - 1, 0, len(k) - 2)
    slope = (t[i + 1] - t[i]) / (k[i + 1] - k[i])
    return np.exp(t[i] + slope * (x - k[i]))
