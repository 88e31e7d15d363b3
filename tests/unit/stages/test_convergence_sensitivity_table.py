"""The convergence-sensitivity table withholds the |K^Stan| counts of an improper posterior in
words (the rule of the verdict), from what its rule's inputs object carries."""

from __future__ import annotations

import numbers

import pandas as pd
import pytest
from factories import same_a09
from ssmobs import io
from ssmobs.config import validation as cfg
from ssmobs.config.stage_inputs.outputs import convergence_sensitivity_inputs
from ssmobs.nuts.convergence import BLOCKS
from ssmobs.reports.propriety_notes import NOT_SHOWN_IMPROPER
from ssmobs.stages.outputs.paper_tables import run_convergence_sensitivity

pytestmark = pytest.mark.unit


def _runs(converged: list[bool]) -> pd.DataFrame:
    """A gather_nuts table: one run per flag, the ones that did not converge failing R-hat
    on the states only (so checking Omega and x0 alone passes them)."""
    return pd.DataFrame(
        [
            {
                **{f"min_ess_{e}_{b}": 900.0 for e in ("bulk", "tail") for b in BLOCKS},
                **{f"max_rhat_{b}": 1.001 for b in ("omega", "x0")},
                "max_rhat_states": 1.001 if ok else 1.2,
                "k": k,
                "status": "ok",
                "converged": ok,
                "failed_checks": "" if ok else "rhat",
                "max_rhat": 1.001 if ok else 1.2,
                "min_ess_bulk": 900.0,
                "min_ess_tail": 800.0,
                "n_divergent": 0.0,
                "n_treedepth_hits": 0.0,
                "min_ebfmi": 0.7,
            }
            for k, ok in enumerate(converged)
        ]
    )


def test_an_improper_posteriors_counts_are_withheld_in_words_a_proper_ones_are_numbers(
    tmp_path,
):
    # model Sep with a flat prior on a: x0 drops out of the likelihood at a = 0, inside it
    improper = same_a09(name="sep_b", model="sep", omega={"a": 0.9, "b": 0.9}, K=6)
    improper["prior"] = {"a": "unrestricted", "b": "restricted"}
    proper = same_a09(name="same", K=4)
    config = cfg.validate({"scenarios": [improper, proper]})
    inputs = convergence_sensitivity_inputs(config, ["sep_b", "same"])
    assert inputs.scenario_names == ["sep_b", "same"]

    paths = {}
    runs = {"sep_b": [True, True, False, True, False, False], "same": [True, True, True, False]}
    for name, converged in runs.items():
        paths[name] = tmp_path / f"{name}.parquet"
        io.write_parquet(paths[name], _runs(converged))
    out = tmp_path / "out"
    table = run_convergence_sensitivity(
        dict(zip(inputs.scenario_names, [paths["sep_b"], paths["same"]], strict=True)),
        inputs.convergence_config,
        [out / f"sens.{ext}" for ext in ("csv", "md", "tex")],
        [out / f"fails.{ext}" for ext in ("csv", "md", "tex")],
        configs=inputs.scenario_entries,
    ).set_index("scenario")

    counts = [c for c in table.columns if c not in ("K", "improper")]
    assert len(counts) >= 7  # K_stan_run and every variant of the checks
    assert (table.loc["sep_b", counts] == NOT_SHOWN_IMPROPER).all()
    assert table.loc["sep_b", "K"] == 6  # the runs stay
    assert "a = 0" in table.loc["sep_b", "improper"]
    assert table.loc["same", "K_stan_run"] == 3 and table.loc["same", "improper"] == ""
    assert table.loc["same", "omega_x0_only"] == table.loc["same", "omega_only"] == 4
    assert all(isinstance(table.loc["same", c], numbers.Integral) for c in counts)

    written = pd.read_csv(out / "sens.csv", keep_default_na=False).set_index("scenario")
    assert (written.loc["sep_b", counts] == NOT_SHOWN_IMPROPER).all()
    assert written.loc["same", "K_stan_run"] == "3" and written.loc["same", "omega_only"] == "4"
    md = (out / "sens.md").read_text()
    assert NOT_SHOWN_IMPROPER in md and "a = 0" in md
    assert 'shows "not shown: improper"' in md.splitlines()[0]  # the caption says why


def test_a_table_of_proper_posteriors_keeps_its_numbers_and_columns(tmp_path):
    config = cfg.validate({"scenarios": [same_a09(name="same", K=2)]})
    inputs = convergence_sensitivity_inputs(config, ["same"])
    io.write_parquet(tmp_path / "same.parquet", _runs([True, False]))
    table = run_convergence_sensitivity(
        {"same": tmp_path / "same.parquet"},
        inputs.convergence_config,
        [tmp_path / "sens.csv"],
        [tmp_path / "fails.csv"],
        configs=inputs.scenario_entries,
    )
    assert "improper" not in table.columns
    assert table["K_stan_run"].tolist() == [1]
    assert "improper" not in (tmp_path / "sens.csv").read_text()
