"""The paper's tables, ours beside the paper's values (config/paper_values.yaml).

Every table is a pandas DataFrame written as CSV, Markdown and LaTeX.  A value the paper
states appears in a ``paper`` column next to ``ours``, with ``rel_diff`` =
RD(ours, paper) = |ours - paper| / max(|ours|, |paper|) (Sec. IV.A); where the paper gives
no value the cells are empty.

A scenario whose posterior is improper (:mod:`ssmobs.reports.propriety_notes`) shows none of
its Stan numbers (|K^Stan|, marginal MAPs, intervals, coverage, bias, MSE) as a number: the
column ``improper`` gives the reason and the cells say "not shown: improper" or are empty;
a documented end-of-support finding is noted in ``edge`` and keeps its numbers.
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import yaml

from .. import io
from ..binomial import clopper_pearson, format_fraction
from ..estimator_moments import EstimatorSummary
from .propriety_notes import (
    NOT_SHOWN_IMPROPER,
    PosteriorNote,
    ProprietyAnalysis,
    add_note_columns,
    config_note,
)


def load_paper_values(path: str | os.PathLike) -> dict[str, Any]:
    return yaml.safe_load(Path(path).read_text())


def rel_diff(ours: float | None, paper: float | None) -> float:
    """RD(ours, paper); NaN when either is missing; 0 when both are 0."""
    if ours is None or paper is None:
        return math.nan
    ours, paper = float(ours), float(paper)
    if not (math.isfinite(ours) and math.isfinite(paper)):
        return math.nan
    den = max(abs(ours), abs(paper))
    return 0.0 if den == 0 else abs(ours - paper) / den


def _get(mapping: Mapping | None, *keys: str) -> Any:
    cur: Any = mapping
    for k in keys:
        if not isinstance(cur, Mapping) or k not in cur:
            return None
        cur = cur[k]
    return cur


def _num(v: Any) -> float:
    return float(v) if v is not None else math.nan


def write_table(
    frame: pd.DataFrame, paths: Sequence[str | os.PathLike], caption: str = ""
) -> list[str]:
    """Write ``frame`` atomically to every path in the format of its suffix (.csv, .md or
    .tex; the caption goes above the Markdown and into the LaTeX table); return the paths."""
    names = [os.fspath(p) for p in paths]
    unknown = [p for p in names if Path(p).suffix not in (".csv", ".md", ".tex")]
    if unknown:
        raise ValueError(f"write_table: {unknown}: the suffix must be .csv, .md or .tex")
    for path in names:
        suffix = Path(path).suffix
        if suffix == ".csv":
            io.write_text(path, frame.to_csv(index=False, float_format="%.6g", na_rep=""))
        elif suffix == ".md":
            shown = frame.astype(object).where(frame.notna(), None)
            md = shown.to_markdown(index=False, floatfmt=".4g", missingval="")
            io.write_text(path, (f"{caption}\n\n" if caption else "") + md + "\n")
        else:
            io.write_text(
                path,
                frame.to_latex(
                    index=False,
                    float_format="%.4g",
                    na_rep="",
                    caption=caption or None,
                    escape=True,
                ),
            )
    return names


# ---------------------------------------------------------------- Table II
STATS = (("mean", "mean"), ("var", "variance"), ("mse", "MSE"))


def _notes(rows: Sequence[dict], propriety: ProprietyAnalysis | None) -> list[PosteriorNote]:
    """The propriety of every row's scenario (its ``config`` entry)."""
    return [config_note(r["config"], propriety) for r in rows]


def table_ii(
    rows: Iterable[dict], paper: Mapping, *, propriety: ProprietyAnalysis | None = None
) -> pd.DataFrame:
    """Table II: empirical mean, variance and MSE of (a, x0), joint vs marginal MAP.

    ``rows``: one dict per scenario with keys ``config`` (its config entry), ``scenario``,
    ``T``, ``paper_ref``, ``joint`` (joint_map summary), ``marginal`` (gather_nuts summary,
    may be None) and ``exact`` (exact_marginal summary at its K, may be None):
    ``<comp>_ours`` is Stan + KDE, ``<comp>_exact`` the exact marginal posterior's
    (marginal-MAP rows only).  A scenario whose posterior is improper leaves its Stan cells
    empty and says why in ``improper``; ``propriety``: the analysis (the project's when None).
    """
    out = []
    notes: list[PosteriorNote] = []
    ordered = sorted(rows, key=lambda r: r["T"])
    for r, note in zip(ordered, _notes(ordered, propriety), strict=True):
        pv = paper.get(r["paper_ref"], {})
        for est_key, stage, est_name in (
            ("joint", "joint", "joint MAP"),
            ("marginal", "stan", "marginal MAP"),
        ):
            summ = EstimatorSummary.read(stage, r.get(est_key))
            exact = EstimatorSummary.read("exact", r.get("exact") if stage == "stan" else None)
            for stat, stat_name in STATS:
                row = {
                    "T": r["T"],
                    "scenario": r["scenario"],
                    "estimator": est_name,
                    "statistic": stat_name,
                }
                hidden = stage == "stan" and note.is_improper
                for comp in ("a", "x0"):
                    ours = math.nan if hidden else summ.stat(comp, stat)
                    ref = _get(pv, est_key, stat, comp)
                    row[f"{comp}_ours"] = ours
                    row[f"{comp}_exact"] = exact.stat(comp, stat)
                    row[f"{comp}_paper"] = _num(ref)
                    row[f"{comp}_rel_diff"] = rel_diff(ours, ref)
                out.append(row)
                notes.append(note)
    add_note_columns(out, notes)
    return pd.DataFrame(out)


# ---------------------------------------------------------------- Table III
#: (label, (component or None for the mean over the states, statistic), the paper's value)
TABLE_III = (
    ("cover90_a", ("a", "cover90"), ("coverage", "cover90", "a")),
    ("cover90_x0", ("x0", "cover90"), ("coverage", "cover90", "x0")),
    ("mean_cover90_states", (None, "cover90"), ("coverage", "mean_cover90_states")),
    ("mean_abs_bias_states", (None, "abs_bias"), ("coverage", "mean_abs_bias_states")),
    ("mean_mse_states", (None, "mse"), ("coverage", "mean_mse_states")),
)


def _table_iii_value(summary: EstimatorSummary, comp: str | None, stat: str) -> float:
    return summary.states(stat) if comp is None else summary.stat(comp, stat)


def table_iii(
    rows: Iterable[dict], paper: Mapping, *, propriety: ProprietyAnalysis | None = None
) -> pd.DataFrame:
    """Table III: Cover90 of (a, x0), mean over t of Cover90(x_t), |Bias(x_t)|, MSE(x_t);
    ``ours`` = Stan + KDE, ``exact`` = exact marginal posteriors (over ``n_exact`` of
    ``K_exact`` trajectories).  A scenario whose posterior is improper leaves ``ours``,
    ``rel_diff`` and ``K_stan`` empty and says why in ``improper``."""
    out = []
    notes: list[PosteriorNote] = []
    ordered = sorted(rows, key=lambda r: r["T"])
    for r, note in zip(ordered, _notes(ordered, propriety), strict=True):
        pv = paper.get(r["paper_ref"], {})
        summ = EstimatorSummary.read("stan", r.get("marginal"))
        exact = EstimatorSummary.read("exact", r.get("exact"))
        for label, (comp, stat), ref_path in TABLE_III:
            ours = math.nan if note.is_improper else _table_iii_value(summ, comp, stat)
            ref = _get(pv, *ref_path)
            out.append(
                {
                    "T": r["T"],
                    "scenario": r["scenario"],
                    "quantity": label,
                    "ours": ours,
                    "exact": _table_iii_value(exact, comp, stat),
                    "paper": _num(ref),
                    "rel_diff": rel_diff(ours, ref),
                    "K_stan": summ.count if summ.present and not note.is_improper else None,
                    "K_exact": exact.get("K"),
                    "n_exact": exact.count if exact.present else None,
                }
            )
            notes.append(note)
    add_note_columns(out, notes)
    return pd.DataFrame(out)


# ---------------------------------------------------------------- Section IV summary
#: (fraction column, count column, K column) of the Section IV summary
FRACTIONS = (
    ("K_max_frac", "K_max", "K"),
    ("K_max_frac_paper", "K_max_paper", "K_paper"),
    ("K_stan_frac", "K_stan", "K_stan_runs"),
    ("K_stan_frac_paper", "K_stan_paper", "K_paper"),
)


def _multi_start_rows(rows: list[dict]) -> bool:
    """Some scenario's joint MAP ran from several starts (its summary has K_max_unique)."""
    return any("K_max_unique" in (r.get("joint") or {}) for r in rows)


#: the Section IV summary's columns that hold a Stan result (a prefix ends in "_")
STAN_RESULT_COLUMNS = (
    "K_stan",
    "K_stan_frac",
    "K_stan_frac_lo95",
    "K_stan_frac_hi95",
    "K_stan_frac_rel_diff",
    "mean_cover90_states",
    "mean_abs_bias_states",
    "mean_mse_states",
    "marginal_",
    "cover90_",
)


def _is_stan_result(column: str) -> bool:
    return any(
        column.startswith(c) if c.endswith("_") else column == c for c in STAN_RESULT_COLUMNS
    )


def section_iv(
    rows: Iterable[dict], paper: Mapping, *, propriety: ProprietyAnalysis | None = None
) -> pd.DataFrame:
    """One row per scenario: settings, |K^max| and |K^Stan| (ours and the paper's, also as
    fractions of K, since our K may be smaller than the paper's) and the estimator
    properties of every Omega component and x0; ``exact_*`` columns: the exact marginal
    stage at its K (``K_exact``): Definition 3's counts (unique / several / none) and the
    same statistics over the ``K_exact_used`` trajectories with a unique maximum.  Every
    fraction ``<f>`` has its exact binomial 95 % interval in ``<f>_lo95`` / ``<f>_hi95``.

    When a scenario's joint MAP ran from several starts (:mod:`ssmobs.joint_map.multi_start`), the
    table also has ``joint_n_starts``, ``K_max_unique`` (trajectories with exactly one
    distinct maximum that passes the checks, from enough starts), ``K_max_undetermined``
    (one maximum, from too few passing starts), ``K_max_several`` and
    ``K_paper_start_highest``, and the fraction ``K_max_unique_frac`` with its interval
    (NaN for single-start scenarios); without any, these columns are absent.

    A scenario whose posterior is improper (``propriety``, the project's analysis when
    None) has its Stan results (:data:`STAN_RESULT_COLUMNS`) empty and the reason in
    ``improper``; ``K_stan_runs`` still counts the runs.  The exact columns stay: they
    describe the posterior restricted to the basin of its interior maximum
    (:mod:`ssmobs.exact.marginal`)."""
    rows = list(rows)
    multi = _multi_start_rows(rows)
    notes = _notes(rows, propriety)
    out = []
    for r, note in zip(rows, notes, strict=True):
        sc = r["config"]
        joint = EstimatorSummary.read("joint", r.get("joint"))
        marg = EstimatorSummary.read("stan", r.get("marginal"))
        ex = EstimatorSummary.read("exact", r.get("exact"))
        pv = paper.get(sc.get("paper_ref", ""), {}) or {}
        K = sc["K"]
        row: dict[str, Any] = {
            "scenario": sc["name"],
            "description": sc.get("description", ""),
            "model": sc["model"],
            "omega": " ".join(f"{k}={v}" for k, v in sc["omega"].items()),
            "x0": str(sc["x0"]),
            "prior": str(r.get("prior", sc.get("prior", ""))),
            "T": sc["T"],
            "K": K,
            "method": sc["method"],
            "stan_init": sc["stan_init"],
            "K_max": joint.count if sc["joint_map"] else math.nan,
            "K_max_paper": _num(pv.get("K_max")),
            "K_paper": _num(pv.get("K")),
            "K_stan": marg.count if sc["stan"] else math.nan,
            # the Stan stage's runs: K, or every stan_every-th of the K (issue 20)
            "K_stan_runs": marg.get("K", math.nan) if sc["stan"] else math.nan,
            "K_stan_paper": _num(pv.get("K_stan")),
        }
        kp = row["K_paper"]
        row["K_max_frac"] = row["K_max"] / K if sc["joint_map"] else math.nan
        row["K_max_frac_paper"] = row["K_max_paper"] / kp if kp else math.nan
        row["K_stan_frac"] = row["K_stan"] / row["K_stan_runs"] if sc["stan"] else math.nan
        row["K_stan_frac_paper"] = row["K_stan_paper"] / kp if kp else math.nan
        row["K_stan_frac_rel_diff"] = rel_diff(row["K_stan_frac"], row["K_stan_frac_paper"])
        for frac, count, total in FRACTIONS:  # exact binomial 95 % interval of every fraction
            row[f"{frac}_lo95"], row[f"{frac}_hi95"] = clopper_pearson(row[count], row[total])
        if multi:
            row["joint_n_starts"] = joint.get("n_starts", 1 if joint.present else math.nan)
            for key in (
                "K_max_unique",
                "K_max_undetermined",
                "K_max_several",
                "K_paper_start_highest",
            ):
                row[key] = _num(joint.get(key))
            row["K_max_unique_frac"] = row["K_max_unique"] / K
            row["K_max_unique_frac_lo95"], row["K_max_unique_frac_hi95"] = clopper_pearson(
                row["K_max_unique"], K
            )
        comps = joint.get("components") or list(sc["omega"]) + ["x0"]
        for c in comps:
            for stat in ("mean", "var", "mse"):
                row[f"joint_{stat}_{c}"] = joint.stat(c, stat)
                row[f"marginal_{stat}_{c}"] = marg.stat(c, stat)
            row[f"cover90_{c}"] = marg.stat(c, "cover90")
        row["mean_cover90_states"] = marg.states("cover90")
        row["mean_abs_bias_states"] = marg.states("abs_bias")
        row["mean_mse_states"] = marg.states("mse")
        row["K_exact"] = ex.get("K", math.nan)
        for kind in ("unique", "several", "none"):
            row[f"exact_{kind}"] = ex.get(f"n_{kind}", math.nan)
        row["exact_unique_frac"] = (
            (row["exact_unique"] / row["K_exact"]) if ex.present else math.nan
        )
        row["exact_unique_frac_lo95"], row["exact_unique_frac_hi95"] = clopper_pearson(
            row["exact_unique"], row["K_exact"]
        )
        row["K_exact_used"] = ex.count
        for c in comps:
            for stat in ("mean", "var", "mse", "cover90"):
                row[f"exact_{stat}_{c}"] = ex.stat(c, stat)
        row["exact_mean_cover90_states"] = ex.states("cover90")
        row["exact_mean_abs_bias_states"] = ex.states("abs_bias")
        row["exact_mean_mse_states"] = ex.states("mse")
        if note.is_improper:
            row.update({k: math.nan for k in row if _is_stan_result(k)})
        out.append(row)
    add_note_columns(out, notes)
    return pd.DataFrame(out)


def section_iv_compact(
    rows: Iterable[dict], paper: Mapping, *, propriety: ProprietyAnalysis | None = None
) -> pd.DataFrame:
    """The Section IV summary a person reads: one row per scenario with T, K, |K^max|/K and
    |K^Stan|/K with their exact binomial 95 % intervals beside the paper's (at the paper's
    K; ours over the Stan runs, K or every ``stan_every``-th of the K), and the
    marginal-MAP mean and Cover90 of every component of Omega and x0 (over K^Stan).  The
    wide table (:func:`section_iv`) holds everything else.  When a scenario's joint MAP ran
    from several starts, |K^max_unique|/K with its interval stands beside |K^max|/K.  A
    scenario whose posterior is improper says "not shown: improper" in its Stan cells and
    why in ``improper``; ``edge`` notes an end-of-support finding (numbers kept)."""
    from ..models import get_model

    rows = list(rows)
    multi = _multi_start_rows(rows)
    notes = _notes(rows, propriety)
    out = []
    for r, note in zip(rows, notes, strict=True):
        sc = r["config"]
        joint = EstimatorSummary.read("joint", r.get("joint"))
        marg = EstimatorSummary.read("stan", r.get("marginal"))
        pv = paper.get(sc.get("paper_ref", ""), {}) or {}
        comps = get_model(sc["model"]).theta_names(0)
        K, K_paper = sc["K"], _num(pv.get("K"))
        k_max = joint.count if sc["joint_map"] else math.nan
        k_stan = marg.count if sc["stan"] else math.nan
        runs = marg.get("K", math.nan) if sc["stan"] else math.nan
        unique = (
            {"K^max_unique/K (95 % CI)": format_fraction(_num(joint.get("K_max_unique")), K)}
            if multi
            else {}
        )
        out.append(
            {
                "scenario": sc["name"],
                "T": sc["T"],
                "K": K,
                "K^max/K (95 % CI)": format_fraction(k_max, K),
                **unique,
                "paper K^max/K": format_fraction(_num(pv.get("K_max")), K_paper),
                "Stan runs": runs,
                "K^Stan/K (95 % CI)": format_fraction(k_stan, runs),
                "paper K^Stan/K": format_fraction(_num(pv.get("K_stan")), K_paper),
                "marginal MAP mean": _per_component(marg, comps, "mean"),
                "Cover90": _per_component(marg, comps, "cover90"),
            }
        )
        if note.is_improper and sc["stan"]:
            for column in ("K^Stan/K (95 % CI)", "marginal MAP mean", "Cover90"):
                out[-1][column] = NOT_SHOWN_IMPROPER
    add_note_columns(out, notes)
    return pd.DataFrame(out)


def _per_component(summary: EstimatorSummary, comps: Sequence[str], stat: str) -> str:
    """``"a 0.897, x0 8.05"``: ``stat`` of every component that has a value."""
    values = ((c, summary.stat(c, stat)) for c in comps)
    return ", ".join(f"{c} {v:.3g}" for c, v in values if math.isfinite(v))


# ---------------------------------------------------------------- K selection
def k_selection_table(rows: Iterable[dict]) -> pd.DataFrame:
    """Chosen K per k_selection entry, method, set variant and seed, with (c1, c2), the grid
    and the paper's K."""
    frame = pd.DataFrame(list(rows))
    cols = [
        "name",
        "scenario",
        "method",
        "sets",
        "seed",
        "c1",
        "c2",
        "K_chosen",
        "K_grid",
        "K_paper",
        "K_paper_range",
        "c_paper",
    ]
    for c in cols:
        if c not in frame.columns:
            frame[c] = np.nan
    return frame[cols]


def k_selection_distribution(table: pd.DataFrame) -> pd.DataFrame:
    """The chosen K as a distribution over seeds (issue 34): per k_selection entry, method,
    set variant and (c1, c2), how many seeds chose each K (``K_chosen`` empty: none on the
    grid) and their share, beside the paper's K; ``table`` is :func:`k_selection_table`."""
    group = ["name", "scenario", "method", "sets", "c1", "c2", "K_grid"]
    rows = []
    for keys, sub in table.groupby(group, sort=False, dropna=False):
        chosen = sub["K_chosen"]
        values = sorted(chosen.dropna().unique()) + ([np.nan] if chosen.isna().any() else [])
        for value in values:
            n = int(chosen.isna().sum() if pd.isna(value) else (chosen == value).sum())
            rows.append(
                {
                    **dict(zip(group, keys)),
                    "seeds": len(sub),
                    "K_chosen": value,
                    "n_seeds": n,
                    "share": n / len(sub),
                    "K_paper": sub["K_paper"].iloc[0],
                }
            )
    return pd.DataFrame(rows, columns=[*group, "seeds", "K_chosen", "n_seeds", "share", "K_paper"])


# ---------------------------------------------------------------- Stan + KDE against exact
EXACT_VS_STAN_STATS = (("map", "marginal MAP"), ("q5", "5 % quantile"), ("q95", "95 % quantile"))


def exact_vs_stan_table(
    stan: pd.DataFrame, exact: pd.DataFrame, names: Sequence[str]
) -> pd.DataFrame:
    """Per component and statistic (marginal MAP, 5 % and 95 % quantiles): the median and
    the largest |Stan + KDE - exact| over the trajectories both hold (issue 11).

    ``stan`` and ``exact`` hold the same trajectories in the same order; a trajectory whose
    difference is not finite is left out of ``n``.
    """
    if len(stan) != len(exact):
        raise ValueError(f"exact_vs_stan_table: {len(stan)} Stan rows, {len(exact)} exact rows")
    rows = []
    for name in names:
        for stat, label in EXACT_VS_STAN_STATS:
            diff = stan[f"{name}_{stat}"].to_numpy(float) - exact[f"{name}_{stat}"].to_numpy(float)
            diff = np.abs(diff[np.isfinite(diff)])
            rows.append(
                {
                    "component": name,
                    "statistic": label,
                    "n": int(diff.size),
                    "abs_diff_median": float(np.median(diff)) if diff.size else np.nan,
                    "abs_diff_max": float(diff.max()) if diff.size else np.nan,
                }
            )
    return pd.DataFrame(
        rows, columns=["component", "statistic", "n", "abs_diff_median", "abs_diff_max"]
    )
