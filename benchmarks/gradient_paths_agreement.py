"""Do the analytic and the autodiff gradient paths give the same answers (issue 63, item 2)?

A committed folder made with Stan's autodiff (read from git at its recorded commit) beside
the same profile regenerated with the analytic gradients, scenario by scenario, for the Stan
numbers of its ``section4_summary.csv``: |K^Stan|/K, the marginal MAP's mean and MSE of each
parameter and x0, Cover90, and the states' mean Cover90, |bias| and MSE.

The two runs need not share their design trajectories (the code between their commits may
have changed the design sets, the joint MAP or the exact stage: the numbers without a sampler
show it), so each Stan number is compared through its distance from the same run's exact
marginal posterior (Sec. III.D), which no sampler touches: D = Stan - exact, of the mean, the
MSE, Cover90 and the states' numbers.  Two runs of samplers with the same stationary
distribution differ in D by Monte Carlo error and by the spread of D over the trajectories
each run has; with the per-trajectory differences c_k of the analytic run (S_k - E_k for a
mean, (S_k - theta)^2 - (E_k - theta)^2 for an MSE, the indicator difference for Cover90,
their means over the states for the states' numbers) the yardstick of D_analytic -
D_autodiff is sqrt(2) sd(c) / sqrt(n).  |K^Stan|/K has no exact counterpart: the binomial
sqrt(2 p (1 - p) / n).  The test: every |z| of a scenario below its Bonferroni bound
z_{1 - 0.05 / (2 m)} over its m numbers.

    .venv/bin/python benchmarks/gradient_paths_agreement.py \
        --folder paper_figures/paper_settings --autodiff-commit d3c2d6e \
        --results /path/to/run/results [--checkout /path/to/its/checkout] > agreement.md
"""

from __future__ import annotations

import argparse
import io
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
from scipy import stats

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "workflow"))

from ssmobs.design.trajectories import read_trajectories  # noqa: E402
from ssmobs.estimator_moments import EstimatorSummary  # noqa: E402
from ssmobs.io import read_json  # noqa: E402

#: the family-wise level of a scenario's comparisons
LEVEL = 0.05
#: the states' numbers: summary column -> per-trajectory statistic of (estimate, truth)
STATES = ("mean_cover90_states", "mean_abs_bias_states", "mean_mse_states")


def committed_csv(commit: str, path: str) -> pd.DataFrame:
    """A CSV file as committed at ``commit``."""
    text = subprocess.run(
        ["git", "-C", str(REPO), "show", f"{commit}:{path}"],
        check=True,
        capture_output=True,
        text=True,
    ).stdout
    return pd.read_csv(io.StringIO(text))


def the_file(pattern: str, results: Path) -> Path:
    """The one file matching ``pattern`` below ``results`` (a run of one config)."""
    found = sorted(results.glob(pattern))
    if len(found) != 1:
        raise SystemExit(f"{results}/{pattern}: {len(found)} files, expected one")
    return found[0]


def per_trajectory(
    scenario: str, results: Path, components: list[str], raw: bool = False
) -> dict[str, np.ndarray]:
    """The per-trajectory differences c_k (Stan - exact) of each number, over the
    trajectories that converged in both; ``raw``: Stan's own values (exact taken as 0), over
    the trajectories that converged in Stan where the scenario has no exact stage."""
    stan = pd.read_parquet(the_file(f"{scenario}/gather_nuts/*/marginal_map.parquet", results))
    traj = read_trajectories(the_file(f"{scenario}/design_trajectories/*/trajectories.nc", results))
    truth = dict(zip([*traj.model.param_names, "x0"], [*traj.omega, traj.x0[0]], strict=True))
    both = stan[stan["converged"]].set_index("k")
    if raw and not list(results.glob(f"{scenario}/exact_marginal/*/marginal_map.parquet")):
        exact = both.reset_index()  # no exact stage: the differences are Stan's own values
    else:
        exact = pd.read_parquet(
            the_file(f"{scenario}/exact_marginal/*/marginal_map.parquet", results)
        )
    ex = exact[exact["converged"]].set_index("k")
    ks = both.index.intersection(ex.index)
    s, e = both.loc[ks], ex.loc[ks]
    out: dict[str, np.ndarray] = {}
    for c in components:
        theta = truth[c]
        keep = 0.0 if raw else 1.0
        out[f"marginal_mean_{c}"] = (s[f"{c}_map"] - keep * e[f"{c}_map"]).to_numpy()
        out[f"marginal_mse_{c}"] = (
            (s[f"{c}_map"] - theta) ** 2 - keep * (e[f"{c}_map"] - theta) ** 2
        ).to_numpy()
        cover_s = (s[f"{c}_q5"] <= theta) & (theta <= s[f"{c}_q95"])
        cover_e = (e[f"{c}_q5"] <= theta) & (theta <= e[f"{c}_q95"])
        out[f"cover90_{c}"] = cover_s.to_numpy(float) - keep * cover_e.to_numpy(float)
    x = traj.x[ks.to_numpy(), :, 0]
    cols = [f"x{t}" for t in range(1, x.shape[1] + 1)]

    def states(frame: pd.DataFrame) -> dict[str, np.ndarray]:
        maps = frame[[f"{c}_map" for c in cols]].to_numpy()
        q5, q95 = (frame[[f"{c}_{q}" for c in cols]].to_numpy() for q in ("q5", "q95"))
        return {
            "mean_cover90_states": ((q5 <= x) & (x <= q95)).mean(axis=1),
            "mean_abs_bias_states": np.abs(maps - x).mean(axis=1),
            "mean_mse_states": ((maps - x) ** 2).mean(axis=1),
        }

    st, ext = states(s), states(e)
    out.update({name: st[name] - (0.0 if raw else ext[name]) for name in STATES})
    return out


def exact_column(name: str) -> str:
    """The summary column of the exact stage's counterpart of Stan number ``name``."""
    return "exact_" + name.replace("marginal_", "")


def run_numbers(scenario: str, results: Path) -> dict[str, float]:
    """The Stan numbers of a run from its gathered summary, for a scenario whose table
    withholds them (an improper posterior: no estimates of it, but still the two samplers'
    outputs on the same target)."""
    marg = EstimatorSummary.read(
        "stan", read_json(the_file(f"{scenario}/gather_nuts/*/summary.json", results))
    )
    out = {"K_stan_frac": marg.count / float(marg.get("K", math.nan))}
    for key in marg.values:
        for stat in ("mean", "mse", "cover90"):
            if key.endswith(f"_{stat}") and not key.startswith("x_"):
                c = key[: -len(stat) - 1]
                name = f"cover90_{c}" if stat == "cover90" else f"marginal_{stat}_{c}"
                out[name] = marg.stat(c, stat)
    for stat in ("cover90", "abs_bias", "mse"):
        out[f"mean_{stat}_states"] = marg.states(stat)
    return out


def number(row: pd.Series, name: str, fallback: dict[str, float] | None = None) -> float:
    """A number of a summary row, or the run's own where the table withholds it."""
    try:
        value = float(row[name])
    except (KeyError, TypeError, ValueError):
        value = math.nan
    return (fallback or {}).get(name, math.nan) if math.isnan(value) else value


def compare(
    folder: str, commit: str, results: Path, checkout: Path = REPO, raw: bool = False
) -> str:
    """The Markdown table and verdicts; ``raw``: Stan's numbers themselves (for runs whose
    exact stage changed between the commits), each with the unpaired yardstick
    sqrt(2) sd / sqrt(n) of its per-trajectory values."""
    old = committed_csv(commit, f"{folder}/section4_summary.csv").set_index("scenario")
    new = pd.read_csv(checkout / folder / "section4_summary.csv").set_index("scenario")
    how = (
        "Stan's numbers themselves; yardstick: the unpaired standard error of their difference"
        if raw
        else "each Stan number beside the same run's exact one; D = Stan - exact; yardstick: "
        "the standard error of D(analytic) - D(autodiff)"
    )
    lines = [
        f"autodiff: `{folder}` at {commit}; analytic: `{folder}` as regenerated; {how} "
        f"(benchmarks/gradient_paths_agreement.py); test: every |z| of a scenario below its "
        f"Bonferroni bound at a family-wise {LEVEL:.0%}",
        "",
        "| scenario | number | autodiff | analytic | difference | yardstick | z |"
        if raw
        else "| scenario | number | autodiff: Stan[, exact] | analytic: Stan[, exact] | "
        "difference (of D where paired) | yardstick | z |",
        "|:--|:--|--:|--:|--:|--:|--:|",
    ]
    verdicts = []
    for scenario in new.index:
        o, a = old.loc[scenario], new.loc[scenario]
        components = [
            c[len("cover90_") :]
            for c in old.columns
            if c.startswith("cover90_") and not c.endswith("states")
        ]
        # D's paired yardstick holds where Stan and the exact stage ran on one set of
        # trajectories: where Stan ran on every m-th only (the summary's exact numbers are
        # over all K), or where some runs failed the checks (each run's numbers are over its
        # own converged subset, which differ by chance), the scenario is compared raw
        # (unpaired, conservative)
        own = run_numbers(scenario, results)
        subset = float(a["K_stan_runs"]) < float(a["K"])
        subsets_differ = any(number(r, "K_stan_frac", own) < 1.0 for r in (o, a))
        paired = not raw and not subset and not subsets_differ
        if not raw and not paired:
            why = (
                "Stan ran on a subset of the trajectories the exact numbers are over"
                if subset
                else "some runs failed the checks, so the two runs' numbers are over "
                "different converged subsets"
            )
            verdicts.append(
                f"{scenario}: {why}; the paired yardstick does not apply: compared raw (unpaired)"
            )
        diffs = per_trajectory(scenario, results, components, not paired)
        rows: list[tuple[str, float, float, float, float, float]] = []
        for name, c in diffs.items():
            ex = exact_column(name)
            so, eo = number(o, name), 0.0 if not paired else number(o, ex)
            sa, ea = number(a, name, own), 0.0 if not paired else number(a, ex)
            stick = math.sqrt(2) * float(np.std(c, ddof=1)) / math.sqrt(c.size)
            rows.append((name, so, eo, sa, ea, stick))
        n_runs = float(a["K_stan_runs"])
        p = number(a, "K_stan_frac", own)
        stick = math.sqrt(2 * max(p * (1 - p), 0.25 / n_runs) / n_runs)
        rows.append(("K_stan_frac", number(o, "K_stan_frac"), 0.0, p, 0.0, stick))
        bound = float(stats.norm.ppf(1 - LEVEL / (2 * len(rows))))
        worst = 0.0
        for name, so, eo, sa, ea, stick in rows:
            diff = (sa - ea) - (so - eo)
            z = diff / stick if stick > 0 else (0.0 if diff == 0 else math.inf)
            worst = max(worst, abs(z))
            alone = not paired or name == "K_stan_frac"
            pair_o = f"{so:.6g}" if alone else f"{so:.6g}, {eo:.6g}"
            pair_a = f"{sa:.6g}" if alone else f"{sa:.6g}, {ea:.6g}"
            lines.append(
                f"| {scenario} | {name} | {pair_o} | {pair_a} | {diff:+.3g} | {stick:.3g} | "
                f"{z:+.2f} |"
            )
        verdicts.append(
            f"{scenario}: largest |z| {worst:.2f} of {len(rows)} numbers, bound {bound:.2f}: "
            f"{'within' if worst < bound else 'NOT within'} Monte Carlo error"
        )
    return "\n".join([*lines, "", *verdicts])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--folder", required=True)
    parser.add_argument("--autodiff-commit", required=True)
    parser.add_argument("--results", required=True, type=Path)
    parser.add_argument(
        "--checkout", type=Path, default=REPO, help="the checkout that holds the regenerated folder"
    )
    parser.add_argument("--raw", action="store_true", help="compare Stan's numbers themselves")
    args = parser.parse_args()
    print(compare(args.folder, args.autodiff_commit, args.results, args.checkout, args.raw))


if __name__ == "__main__":
    main()
