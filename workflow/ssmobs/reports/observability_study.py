"""An observability study of one model over several horizons T (ours, not the paper's).

For the scenarios of one ``observability_studies`` config entry (same model, different T),
one table and one figure of the two observability measures of Sec. III: |K^max|/K (joint
MAP found and passing the checks of Sec. III.B) and |K^Stan|/K (NUTS converged, Sec.
III.C), each with its exact binomial 95 % interval (``_lo95``, ``_hi95``), with the
reasons the others failed (joint-MAP status counts, failed convergence checks), the
marginal-MAP means of Omega over K^Stan and, as a diagnostic of where the draws went,
the median over all K of the KDE modes of Omega (converged or not).
"""

from __future__ import annotations

import os
from collections import Counter
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import pandas as pd

from .. import io
from ..binomial import clopper_pearson
from ..config.scenario import Scenario
from ..estimator_moments import EstimatorSummary
from ..joint_map.checks import STATUSES
from ..nuts.convergence import CHECKS


def _int_or_nan(value: Any) -> float | int:
    """An integer count, or NaN where the summary lacks it (made before the key existed)."""
    return int(value) if value is not None else np.nan


def study_row(
    scenario: Scenario,
    joint: Mapping[str, Any] | None,
    stan: Mapping[str, Any] | None,
    stan_table: pd.DataFrame | None,
) -> dict[str, Any]:
    """One row: T, K, both ratios, why trajectories failed, marginal-MAP means of Omega;
    |K^max_unique|, its ratio and |K^max_undetermined| where the joint MAP ran from several
    starts."""
    model = scenario.model
    row: dict[str, Any] = {
        "scenario": scenario.name,
        "model": model.slug,
        "T": scenario.T,
        "K": scenario.K,
        "method": scenario.method,
    }
    row.update({f"{n}_true": float(v) for n, v in zip(model.param_names, scenario.omega)})
    js, ss = EstimatorSummary.read("joint", joint), EstimatorSummary.read("stan", stan)
    row["K_max"], row["K_max_ratio"] = js.count, js.get("ratio", np.nan)
    row["K_stan"], row["K_stan_ratio"] = ss.count, ss.get("ratio", np.nan)
    # |K^Stan| counts over the Stan runs (every stan_every-th of the K)
    trials = {"K_max": scenario.K, "K_stan": ss.get("K", scenario.K)}
    for ratio, count in (("K_max_ratio", "K_max"), ("K_stan_ratio", "K_stan")):
        row[f"{ratio}_lo95"], row[f"{ratio}_hi95"] = clopper_pearson(row[count], trials[count])
    if js.get("K_max_unique") is not None:  # multi-start joint MAP (ssmobs.joint_map.multi_start)
        unique = int(js.get("K_max_unique"))
        row["K_max_unique"], row["K_max_unique_ratio"] = unique, unique / scenario.K
        lo, hi = clopper_pearson(unique, scenario.K)
        row["K_max_unique_ratio_lo95"], row["K_max_unique_ratio_hi95"] = lo, hi
        # one maximum, but from fewer passing starts than unique_min_share of them
        row["K_max_undetermined"] = _int_or_nan(js.get("K_max_undetermined"))
    if js.present:
        failed = {st: js.get(f"n_{st}", 0) for st in STATUSES if st != "ok"}
        row["joint_not_ok"] = ", ".join(f"{st} {n}" for st, n in failed.items() if n) or "none"
    if stan_table is not None:
        counts: Counter[str] = Counter()
        for checks in stan_table.loc[~stan_table["converged"].astype(bool), "failed_checks"]:
            counts.update(c for c in str(checks).split(",") if c)
        row["stan_failed_checks"] = (
            ", ".join(f"{c} {counts[c]}" for c in CHECKS if counts[c]) or "none"
        )
    bounds = model.prior_bounds(scenario.omega, scenario.prior)
    dropped: list[str] = []
    for i, n in enumerate(model.param_names):
        support = (float(bounds.lower[i]), float(bounds.upper[i]))
        for col, value in (
            (f"{n}_mean_marginal", ss.stat(n, "mean")),
            (f"{n}_mean_joint", js.stat(n, "mean")),
        ):
            why = unusable(value, support)
            row[col] = np.nan if why else value
            if why:
                dropped.append(f"{col} {why}")
    if stan_table is not None:
        # diagnostic, not an estimate: KDE modes of the draws of every k, converged or not;
        # a mode off the support or from draws that ran off is left out and counted
        for i, n in enumerate(model.param_names):
            col = f"{n}_map"
            support = (float(bounds.lower[i]), float(bounds.upper[i]))
            modes = stan_table[col].to_numpy(dtype=float) if col in stan_table else np.array([])
            finite = modes[np.isfinite(modes)]
            reasons = [unusable(float(v), support) for v in finite]
            kept = finite[np.array([not r for r in reasons], dtype=bool)]
            row[f"{n}_map_median_all_k"] = float(np.median(kept)) if kept.size else np.nan
            for reason, n_k in Counter(r for r in reasons if r).items():
                dropped.append(f"{col} of {n_k} k {reason}")
        row["not_shown"] = "; ".join(dropped) or "none"
    elif dropped:
        row["not_shown"] = "; ".join(dropped)
    return row


#: a marginal MAP, quantile or mean beyond this magnitude comes from draws that ran off
RUNOFF_MAGNITUDE = 1e100


def unusable(value: float, support: tuple[float, float]) -> str:
    """Why ``value`` (an estimate of a parameter with prior support ``support``) is not
    shown as a number: off the support or from draws that ran off ("" if usable; NaN is
    "not computed", not a reason)."""
    if not np.isfinite(value):
        return ""
    if abs(value) > RUNOFF_MAGNITUDE:
        return f"from draws that ran off (|value| > {RUNOFF_MAGNITUDE:g})"
    lo, hi = support
    if not lo <= value <= hi:
        return f"off the support ({lo:g}, {hi:g})"
    return ""


def study_table(
    scenarios: Sequence[Scenario],
    joint: Mapping[str, Mapping],
    stan: Mapping[str, Mapping],
    stan_tables: Mapping[str, pd.DataFrame],
) -> pd.DataFrame:
    """Rows of :func:`study_row` sorted by T (a stage not run gives NaN)."""
    rows = [
        study_row(sc, joint.get(sc.name), stan.get(sc.name), stan_tables.get(sc.name))
        for sc in scenarios
    ]
    return pd.DataFrame(rows).sort_values("T", kind="stable").reset_index(drop=True)


def figure_study(frame: pd.DataFrame, title: str, path: str | os.PathLike) -> None:
    """|K^max|/K and |K^Stan|/K against T, each with its 95 % interval as a band."""
    from .figures import _plt, save_figure

    plt = _plt()
    fig, ax = plt.subplots(figsize=(4.6, 3.2))
    ax.plot(frame["T"], frame["K_max_ratio"], "o-", label=r"$|\mathcal{K}^{\max}|/K$ (joint MAP)")
    ax.plot(
        frame["T"],
        frame["K_stan_ratio"],
        "s--",
        label=r"$|\mathcal{K}^{\mathrm{Stan}}|/K$ (marginal MAP)",
    )
    for ratio, colour in (("K_max_ratio", "C0"), ("K_stan_ratio", "C1")):
        ax.fill_between(
            frame["T"],
            frame[f"{ratio}_lo95"].astype(float),
            frame[f"{ratio}_hi95"].astype(float),
            color=colour,
            alpha=0.15,
            lw=0,
        )
    ax.set_xlabel("T")
    ax.set_ylabel("fraction of the K trajectories")
    ax.set_ylim(-0.03, 1.03)
    ax.set_xticks(frame["T"].tolist())
    ax.set_title(title, fontsize=9)
    ax.legend(fontsize=8, loc="best")
    save_figure(fig, [path])
    plt.close(fig)


def run_observability_study(
    study: Mapping[str, Any],
    scenarios: Sequence[Scenario],
    joint: Mapping[str, str],
    stan: Mapping[str, str],
    stan_tables: Mapping[str, str],
    csv: str | os.PathLike,
    md: str | os.PathLike,
    png: str | os.PathLike,
    *,
    stan_settings: Mapping[str, Any] | None = None,
) -> pd.DataFrame:
    """Rule observability_study: read the scenario summaries, write table (CSV, Markdown)
    and figure (PNG)."""
    frame = study_table(
        scenarios,
        {n: io.read_json(p) for n, p in joint.items()},
        {n: io.read_json(p) for n, p in stan.items()},
        {
            n: io.read_parquet(p, required_columns=["converged", "failed_checks"])
            for n, p in stan_tables.items()
        },
    )
    io.write_text(csv, frame.to_csv(index=False, float_format="%.6g", na_rep=""))
    model = scenarios[0].model
    caption = (
        f"Observability of {model.title} ({study['name']}, ours): |K^max|/K (joint MAP, "
        f"Sec. III.B) and |K^Stan|/K (NUTS, Sec. III.C) over T."
    )
    if stan_settings:
        caption += (
            f" Stan: {stan_settings['chains']} chains x ({stan_settings['iter_warmup']}"
            f" + {stan_settings['iter_sampling']}) iterations."
        )
    shown = frame.astype(object).where(frame.notna(), None)
    io.write_text(
        md, caption + "\n\n" + shown.to_markdown(index=False, floatfmt=".4g", missingval="") + "\n"
    )
    figure_study(frame, f"{model.title}: observability over T", png)
    return frame
