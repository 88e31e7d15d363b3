"""An observability study of one model over several horizons T (ours, not the paper's).

For the scenarios of one ``observability_studies`` config entry (same model, different T),
one table and one figure of the two observability measures of Sec. III: |K^max|/K (joint
MAP found and passing the checks of Sec. III.B) and |K^Stan|/K (NUTS converged, Sec.
III.C), each with its exact binomial 95 % interval (``_lo95``, ``_hi95``), with the
reasons the others failed (joint-MAP status counts, failed convergence checks), the
marginal-MAP means of Omega over K^Stan and, as a diagnostic of where the draws went,
the median over all K of the KDE modes of Omega (converged or not).

Every row has ``not_shown`` (which numbers are left out and why: off the prior support, run
off, or an improper posterior; "none") and, with a multi-start joint MAP, ``K_max_unique``
and ``K_max_undetermined``.  A scenario whose posterior is improper
(:mod:`ssmobs.reports.propriety_notes`) shows none of its Stan numbers and gives the reason
in ``improper``; the caption states the NUTS settings that ran ("Stan: off" where none did).
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
from ..nuts.off_support import RUNOFF_MAGNITUDE, unusable
from .propriety_notes import (
    PosteriorNote,
    ProprietyAnalysis,
    add_note_columns,
    posterior_note,
)

__all__ = [
    "RUNOFF_MAGNITUDE",
    "run_observability_study",
    "stan_caption",
    "study_row",
    "study_table",
    "unusable",
]


def _int_or_nan(value: Any) -> float | int:
    """An integer count, or NaN where the summary lacks it (made before the key existed)."""
    return int(value) if value is not None else np.nan


def study_row(
    scenario: Scenario,
    joint: Mapping[str, Any] | None,
    stan: Mapping[str, Any] | None,
    stan_table: pd.DataFrame | None,
    note: PosteriorNote | None = None,
) -> dict[str, Any]:
    """One row: T, K, both ratios, why trajectories failed, marginal-MAP means of Omega;
    |K^max_unique|, its ratio and |K^max_undetermined| where the joint MAP ran from several
    starts; ``not_shown`` ("none" when every number is shown).  ``note``: the posterior's
    propriety; an improper one leaves every Stan number (|K^Stan|, its ratio, the
    marginal-MAP means, the KDE modes) NaN."""
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
    if note is not None and note.is_improper:
        stan_columns = [
            k for k in row if k.startswith(("K_stan", "stan_")) or k.endswith("_marginal")
        ]
        stan_columns += [k for k in row if k.endswith("_map_median_all_k")]
        row.update({k: np.nan for k in stan_columns if k != "stan_failed_checks"})
        dropped = [d for d in dropped if not d.startswith(tuple(stan_columns))]
        dropped.insert(0, "every Stan number (improper posterior)")
    row["not_shown"] = "; ".join(dropped) or "none"
    return row


def study_table(
    scenarios: Sequence[Scenario],
    joint: Mapping[str, Mapping],
    stan: Mapping[str, Mapping],
    stan_tables: Mapping[str, pd.DataFrame],
    *,
    propriety: ProprietyAnalysis | None = None,
) -> pd.DataFrame:
    """Rows of :func:`study_row` sorted by T (a stage not run gives NaN), with the columns
    ``improper`` and ``edge`` where some scenario has such a finding (``propriety``: the
    analysis, the project's when None)."""
    notes = [posterior_note(sc, propriety) for sc in scenarios]
    rows = [
        study_row(sc, joint.get(sc.name), stan.get(sc.name), stan_tables.get(sc.name), note)
        for sc, note in zip(scenarios, notes, strict=True)
    ]
    add_note_columns(rows, notes)
    return pd.DataFrame(rows).sort_values("T", kind="stable").reset_index(drop=True)


def stan_caption(scenarios: Sequence[Scenario], stan_settings: Mapping[str, Any] | None) -> str:
    """What NUTS ran, for a caption: "Stan: off" where no scenario ran it, else the chains and
    iterations of each setting that ran (the scenario's own ``stan_settings`` over the
    config's stan block ``stan_settings``), naming the scenarios where not all share it."""
    ran = [sc for sc in scenarios if sc.stan]
    if not ran:
        return "Stan: off."
    if not stan_settings:
        return ""
    groups: dict[str, list[str]] = {}
    for sc in ran:
        cfg = sc.stan_config(stan_settings)
        text = (
            f"{cfg['chains']} chains x ({cfg['iter_warmup']} + {cfg['iter_sampling']}) iterations"
        )
        groups.setdefault(text, []).append(sc.name)
    off = [sc.name for sc in scenarios if not sc.stan]
    if len(groups) == 1 and not off:
        return f"Stan: {next(iter(groups))}."
    parts = [f"{text} ({', '.join(names)})" for text, names in groups.items()]
    if off:
        parts.append(f"off ({', '.join(off)})")
    return "Stan: " + "; ".join(parts) + "."


def figure_study(frame: pd.DataFrame, title: str, path: str | os.PathLike) -> None:
    """|K^max|/K and |K^Stan|/K against T, each with its 95 % interval as a band; "improper"
    written where a scenario's |K^Stan|/K is not shown."""
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
    if "improper" in frame.columns:  # no |K^Stan|/K of an improper posterior: the word
        for T in frame.loc[frame["improper"].fillna("").astype(bool), "T"]:
            ax.text(T, 0.02, "improper", color="C1", fontsize=7, ha="center", rotation=90)
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
    propriety: ProprietyAnalysis | None = None,
) -> pd.DataFrame:
    """Rule observability_study: read the scenario summaries, write table (CSV, Markdown)
    and figure (PNG); ``stan_settings``: the config's stan block (for the caption)."""
    frame = study_table(
        scenarios,
        {n: io.read_json(p) for n, p in joint.items()},
        {n: io.read_json(p) for n, p in stan.items()},
        {
            n: io.read_parquet(p, required_columns=["converged", "failed_checks"])
            for n, p in stan_tables.items()
        },
        propriety=propriety,
    )
    io.write_text(csv, frame.to_csv(index=False, float_format="%.6g", na_rep=""))
    model = scenarios[0].model
    caption = (
        f"Observability of {model.title} ({study['name']}, ours): |K^max|/K (joint MAP, "
        f"Sec. III.B) and |K^Stan|/K (NUTS, Sec. III.C) over T."
    )
    ran = stan_caption(scenarios, stan_settings)
    caption += f" {ran}" if ran else ""
    shown = frame.astype(object).where(frame.notna(), None)
    io.write_text(
        md, caption + "\n\n" + shown.to_markdown(index=False, floatfmt=".4g", missingval="") + "\n"
    )
    figure_study(frame, f"{model.title}: observability over T", png)
    return frame
