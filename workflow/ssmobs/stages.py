"""Stage-level glue called by the workflow scripts: read inputs, compute, write outputs.

Each function here is what one Snakemake rule does, so a step can be rerun by hand by
calling it with the same paths; the numerics live in the modules it calls.
"""

from __future__ import annotations

import logging
import math
import os
from collections.abc import Iterable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from . import io
from .log import Progress
from .scenario import Scenario

if TYPE_CHECKING:
    import pandas

    from .models.base import StateSpaceModel
    from .stan_backends.base import SamplerSettings

logger = logging.getLogger("ssmobs")

PathLike = str | os.PathLike


# ------------------------------------------------------------------ joint MAP (Sec. III.B)
def _joint_map_of(
    traj: Any, prior: Any, settings: dict, progress: Progress | None = None
) -> tuple[Any, Any, dict, Any]:
    """Joint MAP of every trajectory, its per-k table, its summary and the prior bounds."""
    from .joint_map import JointMapSettings, joint_map, joint_map_summary

    model = traj.model
    bounds = model.prior_bounds(traj.omega, prior)
    result = joint_map(
        model,
        traj.z,
        bounds,
        traj.omega,
        traj.x0,
        JointMapSettings.from_mapping(settings),
        progress=progress,
    )
    frame = result.to_frame(model, traj.T)
    return result, frame, joint_map_summary(frame, model, traj.omega, traj.x0), bounds


def run_joint_map(
    trajectories: PathLike,
    scenario: Scenario,
    settings: dict,
    table: PathLike,
    summary: PathLike,
    theta: PathLike | None = None,
) -> dict:
    """Rule joint_map: joint MAP + checks for every design trajectory of a scenario."""
    from .trajectories import read_trajectories

    traj = read_trajectories(trajectories)
    model = traj.model
    progress = Progress(f"joint MAP {scenario.name}", traj.K, logger)
    settings = {**settings, "start_states": scenario.joint_map_start}
    result, frame, info, bounds = _joint_map_of(traj, scenario.prior, settings, progress)
    info.update(
        scenario=scenario.name,
        model=model.slug,
        T=traj.T,
        method=scenario.method,
        seed=scenario.seed,
        prior=list(bounds.variants),
        start_states=settings["start_states"],
        mu0_median=float(np.nanmedian(frame["mu0"])),
    )
    logger.info("scenario %s: |K^max| = %d of %d", scenario.name, info["K_max"], info["K"])
    io.write_parquet(table, frame)
    if theta is not None:
        io.write_netcdf(
            theta, io.joint_map_dataset(result, model, traj.T, {"scenario": scenario.name})
        )
    io.write_json(summary, info)
    return info


def run_k_selection_point(
    disturbances: PathLike,
    scenario: Scenario,
    K: int,
    method: str,
    seed: int,
    settings: dict,
    out: PathLike,
    sets: str = "independent",
) -> dict:
    """One point of rule k_selection_grid: the joint-MAP summary of one K_i (Sec. IV.A).

    ``seed`` is the run's seed; the set itself was drawn with
    :func:`ssmobs.k_selection.set_seed` (seed, K, sets).
    """
    from .k_selection import set_seed
    from .trajectories import make_trajectories

    sc = scenario.replace(K=K, method=method, seed=set_seed(seed, K, sets))
    matrix, attrs = io.read_disturbances(disturbances, q=sc.disturbance_dim, K=K)
    traj = make_trajectories(sc, matrix, provenance=attrs)
    _, _, info, _ = _joint_map_of(traj, sc.prior, settings)
    info.update(
        K_i=K, method=method, seed=seed, sets=sets, set_seed=sc.seed, scenario=scenario.name
    )
    io.write_json(out, info)
    return info


def disturbance_set(
    path: PathLike, q: int, K: int, method: str, seed: int, design_cfg: dict
) -> tuple[np.ndarray, dict]:
    """The disturbance set cached at ``path`` (the file rule design_disturbances writes),
    made here when it is missing or damaged: the choice of K makes its many small sets in
    the job that scores them instead of one Snakemake job each.  Under a file lock, so two
    jobs never make the same set, and the temporaries a killed maker left are swept."""
    from .design_disturbances import design_disturbances

    path = Path(path)
    with io.file_lock(path.parent / ".locks" / f"{path.name}.lock"):
        io.sweep_temporaries([path])  # no maker runs: we hold the lock
        try:
            return io.read_disturbances(path, q=q, K=K)
        except (FileNotFoundError, io.CorruptFileError):
            pass
        logger.info("design disturbances q=%d K=%d method=%s seed=%d", q, K, method, seed)
        result = design_disturbances(q, K, method, seed, b_max=design_cfg["b_max"])
        io.write_disturbances(path, result)
    return io.read_disturbances(path, q=q, K=K)


def run_k_selection_grid(
    design_dir: PathLike,
    scenario: Scenario,
    K_grid: list[int],
    method: str,
    seed: int,
    sets: str,
    settings: dict,
    design_cfg: dict,
    points_dir: PathLike,
    out: PathLike,
) -> list[dict]:
    """Rule k_selection_grid: V_{K_i} for every K_i of one grid (method, set variant, seed).

    Each point is cached on its own in ``points_dir/K<K_i>.json`` as soon as it is done (a
    rerun after a kill computes only the missing ones), each set in ``design_dir``."""
    from .k_selection import set_seed

    progress = Progress(f"choice of K {scenario.name} {method} {sets} seed {seed}", len(K_grid))
    rows = []
    for K in K_grid:
        point = Path(points_dir) / f"K{K}.json"
        info = None
        if point.exists():
            try:
                info = io.read_json(point, required=["K_i", "method", "seed"])
            except io.CorruptFileError as err:
                logger.warning("recomputing: %s", err)
        if info is None:
            s = set_seed(seed, K, sets)
            path = Path(design_dir) / f"q{scenario.disturbance_dim}_K{K}_{method}_seed{s}.nc"
            disturbance_set(path, scenario.disturbance_dim, K, method, s, design_cfg)
            info = run_k_selection_point(path, scenario, K, method, seed, settings, point, sets)
        rows.append(info)
        progress.update()
    io.write_json(out, {"points": rows})
    return rows


def mu0_sweep_rows(traj: Any, prior: Any, settings: dict, mu0_per_T: list[float]) -> list[dict]:
    """|K^max|/K of one scenario's joint MAP for mu_0 = f * T (f in ``mu0_per_T``) and for the
    gradient-balance rule (:func:`ssmobs.joint_map.initial_mu_values`)."""
    rows = []
    variants: list[tuple[str, dict[str, Any]]] = [
        ("gradient balance", {"mu0_rule": "gradient_balance"})
    ]
    variants += [
        (f"{f:g} T", {"mu0_rule": "per_step", "mu0": f * traj.T, "mu0_per_step": 0.0})
        for f in mu0_per_T
    ]
    for label, extra in variants:
        result, frame, info, _ = _joint_map_of(traj, prior, {**settings, **extra})
        rows.append(
            {
                "mu0": label,
                "mu0_over_T_median": float(np.median(result.mu_start)) / traj.T,
                "ratio": info["ratio"],
                "K_max": info["K_max"],
                "K": info["K"],
                "n_boundary": info["n_boundary"],
            }
        )
    return rows


def run_joint_map_mu0_sweep(
    trajectories: dict[str, PathLike],
    scenarios: dict[str, Scenario],
    settings: dict,
    mu0_per_T: list[float],
    paper_values: PathLike,
    paths: list[PathLike],
) -> pandas.DataFrame:
    """Rule joint_map_mu0_sweep: |K^max|/K of the Sep models over a range of barrier starts.

    One row per mu_0 setting (the gradient-balance rule first, with its median mu_0 / T),
    one column per scenario with its exact binomial 95 % interval (``lo95``, ``hi95``), and
    a last row with the paper's |K^max| / K where stated; written to ``paths`` (.csv, .md,
    .tex).
    """
    import pandas as pd

    from .binomial import clopper_pearson
    from .tables import load_paper_values, write_table
    from .trajectories import read_trajectories

    paper = load_paper_values(paper_values)
    table: dict[str, dict] = {}
    paper_row: dict[str, Any] = {"mu0": "paper"}
    for name, path in trajectories.items():
        sc = scenarios[name]
        traj = read_trajectories(path)
        for row in mu0_sweep_rows(traj, sc.prior, settings, mu0_per_T):
            entry = table.setdefault(row["mu0"], {"mu0": row["mu0"]})
            entry[f"{name} K^max/K"] = row["ratio"]
            entry[f"{name} K^max/K lo95"], entry[f"{name} K^max/K hi95"] = clopper_pearson(
                row["K_max"], row["K"]
            )
            if row["mu0"] == "gradient balance":
                entry[f"{name} mu0/T"] = row["mu0_over_T_median"]
        ref = paper.get(sc.paper_ref, {}) or {}
        stated = ref.get("K_max") is not None and ref.get("K")
        paper_row[f"{name} K^max/K"] = ref["K_max"] / ref["K"] if stated else None
        paper_row[f"{name} K^max/K lo95"], paper_row[f"{name} K^max/K hi95"] = (
            clopper_pearson(ref["K_max"], ref["K"]) if stated else (None, None)
        )
        logger.info("mu0 sweep: %s done", name)
    frame = pd.DataFrame([*table.values(), paper_row])
    cols = ["mu0"] + [c for c in frame.columns if " K^max/K" in c]
    cols += [c for c in frame.columns if c.endswith("mu0/T")]
    frame = frame[cols]
    write_table(
        frame,
        paths,
        "Joint MAP, |K^max|/K of the Sep models for barrier starts mu_0 = f T and for "
        "the gradient-balance rule (mu0/T: its median over k), with the paper's",
    )
    return frame


# ------------------------------------------------------------------ Stan stage (Sec. III.C)
def batches(K: int, batch_size: int) -> list[range]:
    """Contiguous trajectory ranges of the Stan jobs: a pure function of (K, batch_size)."""
    return [range(b, min(b + batch_size, K)) for b in range(0, K, batch_size)]


def sampler_settings(stan_cfg: dict, threads: int = 1) -> SamplerSettings:
    from .stan_backends.base import SamplerSettings

    return SamplerSettings(
        chains=stan_cfg["chains"],
        iter_warmup=stan_cfg["iter_warmup"],
        iter_sampling=stan_cfg["iter_sampling"],
        adapt_delta=stan_cfg["adapt_delta"],
        max_treedepth=stan_cfg["max_treedepth"],
        workers=max(1, threads),
    )


def run_build_stan_model(model: str, backend: str, out: PathLike) -> dict:
    """Rule build_stan_model: compile stan/<model>.stan once; write the backend's marker."""
    from .stan_backends import get_backend, stan_file

    marker = get_backend(backend).compile(stan_file(model))
    io.write_json(out, marker)
    return marker


def run_sample_batch(
    trajectories: PathLike,
    marker: PathLike,
    scenario: Scenario,
    stan_cfg: dict,
    convergence_cfg: dict,
    batch: int,
    records_dir: PathLike,
    draws_dir: PathLike,
    out: PathLike,
    threads: int = 1,
) -> None:
    """Rule sample_nuts: NUTS, checks and marginal MAPs for one batch of trajectories.

    Each trajectory's record is written on its own as soon as it is done; a rerun after an
    interruption reuses every valid record (see :func:`ssmobs.nuts_stage.run_trajectories`).
    """
    from .convergence import ConvergenceSettings, apply_thresholds
    from .nuts_stage import records_to_frame, run_trajectories
    from .stan_backends import get_backend, stan_file
    from .trajectories import read_trajectories

    traj = read_trajectories(trajectories)
    model = traj.model
    backend_name = io.read_json(marker, required=["backend"])["backend"]
    ks = list(batches(traj.K, scenario.batch_size(stan_cfg))[batch])
    bounds = model.prior_bounds(traj.omega, scenario.prior)
    progress = Progress(f"NUTS {scenario.name} batch {batch}", len(ks), logger)
    records = run_trajectories(
        model,
        get_backend(backend_name),
        stan_file(model.slug),
        traj.z,
        traj.x,
        ks,
        bounds,
        traj.omega,
        traj.x0,
        scenario.name,
        scenario.seed,
        sampler=sampler_settings(stan_cfg, threads),
        convergence=ConvergenceSettings(**convergence_cfg),
        init=scenario.stan_init,
        records_dir=records_dir,
        keep_draws_for=set(stan_cfg["keep_draws"]) & set(ks),
        draws_dir=draws_dir,
        progress=progress,
    )
    settings = ConvergenceSettings(**convergence_cfg)
    io.write_parquet(out, apply_thresholds(records_to_frame(records, model, traj.T), settings))


def _damaged_batch(batch_table: PathLike, what: str) -> io.CorruptFileError:
    return io.CorruptFileError(
        f"{batch_table}: {what}; this batch must be rerun (only damaged records are recomputed)"
    )


def changed_batch_records(
    batch_table: PathLike,
    records_dir: PathLike,
    draws_dir: PathLike | None = None,
    keep_draws: Iterable[int] = (),
) -> str | None:
    """Why the finished batch table ``batch_table`` no longer matches its records, or None.

    Reads only the table's ``k`` column, the records' file times and, for the
    ``keep_draws`` trajectories, the kept draws' checksums (cheap enough for every DAG
    build): a record of one of those k that is missing or newer than the table was
    damaged, edited or deleted after the batch ran; a kept draws file that is missing or
    differs from the checksum its record holds was
    damaged.  None when the table does not exist (the batch is still to run) or cannot be
    read (gather_nuts reports that).
    """
    import pyarrow.parquet as pq

    from .record_cache import draws_path, record_path

    table = Path(batch_table)
    keep = {int(k) for k in keep_draws}
    try:
        written = table.stat().st_mtime_ns
        ks = pq.read_table(table, columns=["k"]).column("k").to_pylist()
    except Exception:  # noqa: BLE001 - missing or unreadable: not this check's business
        return None
    for k in ks:
        path = record_path(records_dir, k)
        try:
            changed = path.stat().st_mtime_ns > written
        except FileNotFoundError:
            return str(_damaged_batch(table, f"the record of trajectory k={k} ({path}) is missing"))
        if changed:
            return str(
                _damaged_batch(
                    table,
                    f"the record of trajectory k={k} ({path}) was "
                    f"changed after this table was written",
                )
            )
        if draws_dir is None or k not in keep:
            continue  # only the records of kept draws are read (this runs on every DAG build)
        draws = draws_path(draws_dir, k)
        try:
            expected = (io.read_json(path) or {}).get("draws_sha256")
        except io.CorruptFileError:
            return str(_damaged_batch(table, f"the record of trajectory k={k} is damaged"))
        if expected and (not draws.exists() or io.file_sha256(draws) != expected):
            return str(_damaged_batch(table, f"the kept draws {draws} are missing or damaged"))
    return None


def check_batch_records(
    batch_table: PathLike,
    frame: pandas.DataFrame,
    model: StateSpaceModel,
    T: int,
    records_dir: PathLike,
    convergence_cfg: dict,
) -> None:
    """The per-trajectory records a batch table was built from are all there, parse and
    give exactly this table (:func:`ssmobs.nuts_stage.records_to_frame`).

    Run by gather_nuts (the workflow also stops before it when a record is newer than its
    table, :func:`changed_batch_records`).  Raises
    :class:`~ssmobs.io.CorruptFileError` naming the batch table to delete: rerunning its
    batch recomputes the damaged records only and reuses every valid one.
    """
    from .convergence import ConvergenceSettings, apply_thresholds
    from .nuts_stage import records_to_frame
    from .record_cache import RECORD_KEYS, record_path

    def damaged(what: str) -> io.CorruptFileError:
        return _damaged_batch(batch_table, what)

    recs = []
    for k in frame["k"].tolist():
        path = record_path(records_dir, k)
        if not path.exists():
            raise damaged(f"the record of trajectory k={k} ({path}) is missing")
        try:
            rec = io.read_json(path, required=RECORD_KEYS)
        except io.CorruptFileError as err:
            raise damaged(f"the record of trajectory k={k} is damaged ({err.args[0]})") from None
        if rec["k"] != k:
            raise damaged(f"the record {path} is of trajectory k={rec['k']}, not k={k}")
        recs.append(rec)
    try:
        rebuilt = apply_thresholds(
            records_to_frame(recs, model, T), ConvergenceSettings(**convergence_cfg)
        )
    except (KeyError, TypeError, ValueError, IndexError) as err:
        raise damaged(f"its records under {records_dir} do not form a table ({err})") from None
    if list(rebuilt.columns) != list(frame.columns) or len(rebuilt) != len(frame):
        raise damaged(f"its records under {records_dir} give other columns or rows")
    if not rebuilt.equals(frame):
        bad = [
            int(k)
            for k, (_, a), (_, b) in zip(frame["k"], rebuilt.iterrows(), frame.iterrows())
            if not a.equals(b)
        ]
        raise damaged(f"the records of trajectories k={bad} ({records_dir}) differ from it")


def run_gather_nuts(
    trajectories: PathLike,
    batch_tables: list[PathLike],
    scenario: Scenario,
    convergence_cfg: dict,
    records_dir: PathLike,
    table: PathLike,
    summary: PathLike,
) -> dict:
    """Rule gather_nuts: one table of all trajectories and the scenario's Stan summary.

    The batch tables hold the configured convergence checks applied to the records'
    diagnostics (:func:`ssmobs.convergence.apply_thresholds`), so other thresholds rebuild
    the tables without new sampling."""
    import pandas as pd

    from .stan_metrics import stan_summary
    from .trajectories import read_trajectories

    traj = read_trajectories(trajectories)
    frames = [io.read_parquet(p, required_columns=["k", "converged"]) for p in batch_tables]
    for path, batch_frame in zip(batch_tables, frames):
        check_batch_records(path, batch_frame, traj.model, traj.T, records_dir, convergence_cfg)
    frame = pd.concat(frames, ignore_index=True)
    frame = frame.sort_values("k", kind="stable").reset_index(drop=True)
    if frame["k"].tolist() != list(range(traj.K)):
        raise io.CorruptFileError(
            f"batch tables of scenario {scenario.name} do not cover "
            f"k = 0..{traj.K - 1} exactly once"
        )
    info = stan_summary(frame, traj.model, traj.omega, traj.x0, traj.x)
    info.update(
        scenario=scenario.name, model=traj.model.slug, T=traj.T, stan_init=scenario.stan_init
    )
    logger.info("scenario %s: |K^Stan| = %s of %d", scenario.name, info["n_stan"], traj.K)
    io.write_parquet(table, frame)
    io.write_json(summary, info)
    return info


def run_convergence_sensitivity(
    tables: dict[str, PathLike], convergence_cfg: dict, paths: list[PathLike]
) -> pandas.DataFrame:
    """Rule convergence_sensitivity: |K^Stan| per scenario under other R-hat / tree-depth rules.

    Re-evaluates the stored per-trajectory diagnostics (no new sampling); ``tables`` maps
    scenario names to their gather_nuts tables.
    """
    from .convergence import ConvergenceSettings, sensitivity_table
    from .tables import write_table

    frames = {
        name: io.read_parquet(path, required_columns=["k", "converged", "failed_checks"])
        for name, path in tables.items()
    }
    base = ConvergenceSettings(**convergence_cfg)
    table = sensitivity_table(frames, base)
    write_table(
        table,
        paths,
        "|K^Stan| under R-hat < 1.01 or < 1.05 and tree-depth saturation warned about "
        f"or counted as a failure (other thresholds as configured: divergences <= "
        f"{base.max_divergences}, ESS >= {base.ess_bulk_min:g}/{base.ess_tail_min:g}, "
        f"E-BFMI >= {base.ebfmi_min:g})",
    )
    return table


# ------------------------------------------------------------------ paper tables and figures
def _maybe_json(path: PathLike | None) -> dict | None:
    return io.read_json(path) if path else None


def _table_ii_setting(rows: list[dict]) -> str:
    """The caption's setting, "model Same, (a, x0) = (0.9, 8)", when the rows share it."""
    settings = set()
    for r in rows:
        sc = Scenario.from_config(r["config"])
        a = dict(zip(sc.model.param_names, sc.omega)).get("a", float("nan"))
        settings.add((sc.model.slug, float(a), tuple(float(v) for v in sc.x0)))
    if len(settings) != 1:
        return "the scenarios of paper_outputs.tables_2_3"
    ((slug, a, x0),) = settings
    x0_text = ", ".join(f"{v:g}" for v in x0)
    return f"model {slug.replace('_', ' ').title()}, (a, x0) = ({a:g}, {x0_text})"


def run_paper_tables(
    scenarios: list[dict],
    tables_2_3: list[str],
    joint: dict[str, str],
    marginal: dict[str, str],
    paper_values: PathLike,
    table2: list[PathLike],
    table3: list[PathLike],
    section4_csv: PathLike,
    section4: list[PathLike],
    exact: dict[str, str] | None = None,
) -> dict[str, Any]:
    """Rule paper_tables: Table II, Table III and the Section IV summary, paper values beside.

    ``tables_2_3``: names of the scenarios of Tables II and III (``paper_outputs``);
    ``joint`` / ``marginal`` / ``exact`` map scenario names to their summary JSON paths.
    ``table2``, ``table3``, ``section4``: the paths to write (.csv, .md, .tex by suffix);
    the Section IV summary goes whole to ``section4_csv`` and as the compact table a
    person reads (:func:`ssmobs.tables.section_iv_compact`) to ``section4``.
    """
    exact = exact or {}
    from . import tables

    paper = tables.load_paper_values(paper_values)
    rows = []
    for sc in scenarios:
        j = _maybe_json(joint.get(sc["name"]))
        m = _maybe_json(marginal.get(sc["name"]))
        rows.append(
            {
                "config": sc,
                "scenario": sc["name"],
                "T": sc["T"],
                "paper_ref": sc.get("paper_ref", ""),
                "joint": j,
                "marginal": m,
                "exact": _maybe_json(exact.get(sc["name"])),
                "prior": (j or {}).get("prior", sc.get("prior", "")),
            }
        )
    by_name = {r["scenario"]: r for r in rows}
    t2_rows = [by_name[n] for n in tables_2_3]
    frames = {
        "table2_joint_vs_marginal": (
            tables.table_ii(t2_rows, paper),
            table2,
            "Table II: empirical mean, variance and MSE of (a, x0), "
            f"{_table_ii_setting(t2_rows)}; ours (Stan + KDE), exact "
            "and the paper's",
        ),
        "table3_coverage": (
            tables.table_iii(t2_rows, paper),
            table3,
            "Table III: coverage of the 90% intervals, mean |bias| and MSE of "
            "the states (marginal MAP); ours (Stan + KDE), exact and the "
            "paper's",
        ),
        "section4_summary": (tables.section_iv(rows, paper), [section4_csv], ""),
        "section4_compact": (
            tables.section_iv_compact(rows, paper),
            section4,
            "Section IV: every scenario, the observability fractions "
            "|K^max|/K (joint MAP) and |K^Stan|/K (Stan) with their exact "
            "binomial 95 % intervals, ours beside the paper's (at the paper's "
            "K), and the marginal MAP's mean and Cover90 over K^Stan; every "
            "other column is in section4_summary.csv",
        ),
    }
    for frame, paths, caption in frames.values():
        tables.write_table(frame, paths, caption)
    return {k: v[0] for k, v in frames.items()}


def run_figure_joint_vs_marginal(
    scenarios: list[dict],
    joint_tables: dict[str, str],
    marginal_tables: dict[str, str],
    paths: list[str],
) -> None:
    """Rule figure_joint_vs_marginal: Figure 3 from the per-k tables of both stages.

    ``scenarios``: those of ``paper_outputs.figure3`` (one model, Omega and x0, checked by
    the config); the first parameter of the model is plotted against x0, with the true
    values as lines.  No scenarios: empty panels (and the paper's (a, x0) = (0.9, 8))."""
    import pandas as pd

    from .figures import figure_joint_vs_marginal
    from .models import get_model

    name, truth = "a", (0.9, 8.0)
    if scenarios:
        name = get_model(scenarios[0]["model"]).param_names[0]
        truth = (float(scenarios[0]["omega"][name]), float(scenarios[0]["x0"]))
    panels = []
    for sc in sorted(scenarios, key=lambda s: s["T"]):
        j = io.read_parquet(joint_tables[sc["name"]], ["status", name, "x0"])
        m = io.read_parquet(marginal_tables[sc["name"]], ["converged", f"{name}_map", "x0_map"])
        panels.append(
            {
                "T": sc["T"],
                "joint": j[j["status"] == "ok"],
                "marginal": m[m["converged"].astype(bool)],
            }
        )
    if not panels:
        panels = [
            {
                "T": "-",
                "joint": pd.DataFrame({name: [], "x0": []}),
                "marginal": pd.DataFrame({f"{name}_map": [], "x0_map": []}),
            }
        ]
    figure_joint_vs_marginal(panels, *truth, paths, name=name)


def run_figure_observability(summary_csv: PathLike, paths: list[str]) -> None:
    """Rule figure_observability: |K^max|/K and |K^Stan|/K of every scenario."""
    import pandas as pd

    from .figures import figure_observability_ratios

    figure_observability_ratios(pd.read_csv(summary_csv), paths)


# ------------------------------------------------------------------ choice of K (Sec. IV.A)
def run_select_k(
    ksel: dict,
    scenario: Scenario,
    grids: list[PathLike],
    paper_values: PathLike,
    out_json: PathLike,
    out_csv: PathLike,
    figure_paths: list[str],
) -> dict:
    """Rule select_k: the RD rule over K_grid for every method, set variant and seed
    (:func:`ssmobs.k_selection.choose_k`); the V components as CSV and the figure."""
    import pandas as pd

    from .figures import figure_k_convergence
    from .k_selection import choose_k
    from .tables import load_paper_values

    summaries = [row for p in grids for row in io.read_json(p, required=["points"])["points"]]
    paper = load_paper_values(paper_values).get(scenario.paper_ref, {}) or {}
    long_rows, choices = choose_k(summaries, scenario.model, ksel, scenario.name, paper)
    frame = pd.DataFrame(long_rows)
    io.write_text(out_csv, frame.to_csv(index=False, float_format="%.10g"))
    chosen = pd.DataFrame(choices)
    # one line per method, set variant and seed in the figure
    figure_k_convergence(
        frame.assign(method=frame["method"] + " " + frame["sets"]),
        chosen.assign(
            K_chosen=chosen["K_chosen"].astype(float),
            method=chosen["method"] + " " + chosen["sets"],
        ),
        f"choice of K: {ksel['name']} (c1={ksel['c1']}, c2={ksel['c2']})",
        figure_paths,
    )
    io.write_json(out_json, {"choices": choices})
    return {"choices": choices}


def run_table_k_selection(selections: list[PathLike], paths: list[PathLike]) -> None:
    """Rule table_k_selection: chosen K per k_selection entry, method and seed."""
    from .tables import k_selection_table, write_table

    rows = [c for p in selections for c in io.read_json(p, required=["choices"])["choices"]]
    write_table(
        k_selection_table(rows),
        paths,
        "Choice of K by relative differences (Sec. IV.A): ours per method, set variant "
        "(independent sets per K_i, or nested: one seed for all K_i) and seed, beside "
        "the paper's",
    )


def run_figure_profile_posterior(
    trajectories: PathLike, scenario: Scenario, grid: dict, paths: list[str]
) -> None:
    """Rule figure_profile_posterior: Figure 4 for trajectory k = 0 of a ranWalk scenario."""
    from .figures import figure_profile_posterior
    from .profile_posterior import profile_posterior
    from .trajectories import read_trajectories

    traj = read_trajectories(trajectories)
    model = traj.model
    bounds = model.prior_bounds(traj.omega, scenario.prior)
    a = np.linspace(grid["a_min"], grid["a_max"], grid["n"])
    x0 = np.linspace(grid["x0_min"], grid["x0_max"], grid["n"])
    values = profile_posterior(model, traj.z[0], bounds, model.param_names[0], a, x0)
    figure_profile_posterior(
        a,
        x0,
        values,
        float(traj.omega[0]),
        float(traj.x0[0]),
        f"profile posterior, {model.title}, T={traj.T}, k=1",
        paths,
    )


# ------------------------------------------------------------------ exact marginal (issue 11)
def exact_summary(
    frame: Any, model: StateSpaceModel, omega: Any, x0: Any, x_true: np.ndarray
) -> dict:
    """The Stan stage's statistics (:func:`ssmobs.stan_metrics.stan_summary`, over the
    trajectories with a unique interior maximum) plus Definition 3's counts and the share of
    trajectories whose posterior is improper at each boundary."""
    from .exact_marginal import MAXIMA_KINDS
    from .stan_metrics import stan_summary

    info = stan_summary(frame, model, omega, x0, x_true)
    info["n_exact"] = info["n_stan"]
    for kind in MAXIMA_KINDS:
        info[f"n_{kind}"] = int((frame["maxima"] == kind).sum())
    info["n_box_truncated"] = int(frame["box_truncated"].sum())
    info["n_spike_not_negligible"] = int((frame["converged"] & frame["spike_not_negligible"]).sum())
    for name in model.param_names:
        for side in ("lower", "upper"):
            col = frame[f"improper_{side}_{name}"]
            info[f"improper_{side}_{name}_share"] = float(col.mean()) if len(col) else math.nan
            slopes = frame[f"slope_{side}_{name}"].to_numpy(dtype=float)
            info[f"slope_{side}_{name}_median"] = (
                float(np.nanmedian(slopes)) if np.isfinite(slopes).any() else math.nan
            )
    return info


def run_exact_marginal(
    trajectories: PathLike, scenario: Scenario, table: PathLike, summary: PathLike
) -> dict:
    """Rule exact_marginal: exact marginal posteriors of every design trajectory."""
    import time

    from .exact_marginal import exact_marginal
    from .trajectories import read_trajectories

    traj = read_trajectories(trajectories)
    model = traj.model
    if not model.linear_in_states:
        raise ValueError(
            f"scenario {scenario.name}: model '{model.slug}' is not linear "
            f"in the states; the exact stage does not apply"
        )
    bounds = model.prior_bounds(traj.omega, scenario.prior)
    start = time.perf_counter()
    result = exact_marginal(model, traj.z, bounds)
    seconds = time.perf_counter() - start
    frame = result.to_frame(model)
    info = exact_summary(frame, model, traj.omega, traj.x0, traj.x)
    info.update(
        scenario=scenario.name,
        model=model.slug,
        T=traj.T,
        grid=result.info,
        prior=list(bounds.variants),
    )
    logger.info(
        "scenario %s (exact): %d of %d with a unique interior maximum, %.1f s",
        scenario.name,
        info["n_exact"],
        traj.K,
        seconds,
    )
    io.write_parquet(table, frame)
    io.write_json(summary, info)
    return info


def run_figure_exact_vs_stan(
    scenario: Scenario, stan_table: PathLike, exact_table: PathLike, paths: list[str]
) -> dict:
    """Rule figure_exact_vs_stan: Stan + KDE marginal MAP against the exact one, per k."""
    from .figures import figure_exact_vs_stan

    model = scenario.model
    names = list(model.param_names) + (
        ["x0"] if model.state_dim == 1 else [f"x0_{i + 1}" for i in range(model.state_dim)]
    )
    cols = ["k", "converged"] + [f"{n}_{s}" for n in names for s in ("map", "q5", "q95")]
    stan = io.read_parquet(stan_table, cols)
    exact = io.read_parquet(exact_table, cols)
    if stan["k"].tolist() != exact["k"].tolist():
        raise ValueError(
            f"scenario {scenario.name}: the Stan and exact tables hold "
            f"different trajectories (K = {len(stan)} and {len(exact)})"
        )
    both = stan["converged"].to_numpy(bool) & exact["converged"].to_numpy(bool)
    return figure_exact_vs_stan(stan[both], exact[both], names, scenario.name, paths)
