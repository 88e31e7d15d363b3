"""The variant x row table (issue 20): labels derived from the Stan set-up, variants refused
when they ran on other trajectories, and the committed table is what the committed studies
give today."""

from __future__ import annotations

import json
from pathlib import Path

import pandas as pd
import pytest
from repo_paths import REPO_DIR
from ssmobs.config.validation import ConfigError, validate
from ssmobs.reports.stan_variants import (
    OURS,
    VariantTableError,
    caption,
    read_spec,
    setup_label,
    spec_inputs,
    stan_setup,
    table_key,
    variant_by_row,
    variant_rows,
    write_variant_table,
)

SPEC = REPO_DIR / "config/tables/stan_variants_by_row.yaml"

SCENARIO = {
    "name": "base",
    "model": "same",
    "omega": {"a": 0.7},
    "x0": 8,
    "T": 20,
    "K": 40,
    "prior": "restricted",
    "stan_every": 2,
    "paper_ref": "same_a07_T100",
}


def _study(
    folder: Path, scenarios: list[dict], converged: dict[str, int], extra: dict | None = None
) -> Path:
    """A committed-looking folder: provenance.json with the config (``extra``: more of its
    keys), a Section IV summary."""
    folder.mkdir(parents=True)
    config = {"outputs_dir": "x", "scenarios": scenarios, **(extra or {})}
    (folder / "provenance.json").write_text(json.dumps({"config": config}))
    pd.DataFrame(
        [
            {
                "scenario": s["name"],
                "K_stan": converged[s["name"]],
                "K_stan_runs": 20,
                "K_stan_frac": converged[s["name"]] / 20,
                "K_stan_frac_lo95": 0.0,
                "K_stan_frac_hi95": 1.0,
                "K_stan_frac_paper": 0.808,
            }
            for s in scenarios
        ]
    ).to_csv(folder / "section4_summary.csv", index=False)
    return folder


def test_labels_say_what_differs_from_the_rows_own_setup():
    config = {"stan": {"chains": 4, "iter_warmup": 10, "init_radius": 2, "adapt_delta": 0.8}}
    base = stan_setup(config, {"stan_init": "true"})
    assert setup_label(base, base) == OURS
    seeded = stan_setup(config, {"stan_init": "true", "stan_seed": 2})
    assert setup_label(seeded, base) == "one Stan seed (2) for all"
    zero = stan_setup(config, {"stan_settings": {"init_radius": 0}})
    assert setup_label(zero, stan_setup(config, {})) == "every chain at 0"
    both = stan_setup(config, {"stan_settings": {"adapt_delta": 0.95, "iter_warmup": 80}})
    assert setup_label(both, stan_setup(config, {})) == "warmup 80, adapt_delta 0.95"


def test_the_gradient_path_is_a_setup_of_its_own():
    """Issue 49: the analytic path beside a row run with Stan's autodiff (the default)."""
    autodiff = stan_setup(validate({"outputs_dir": "x", "scenarios": [SCENARIO]}), SCENARIO)
    analytic_config = validate(
        {"outputs_dir": "x", "stan": {"gradients": "analytic"}, "scenarios": [SCENARIO]}
    )
    analytic = stan_setup(analytic_config, SCENARIO)
    assert autodiff["gradients"] == "autodiff"
    assert setup_label(analytic, autodiff) == "analytic gradients"
    assert setup_label(autodiff, analytic) == "Stan's autodiff gradients"


def test_variants_line_up_under_their_rows_baseline(tmp_path):
    base = _study(tmp_path / "row", [SCENARIO], {"base": 15})
    variants = [
        {**SCENARIO, "name": "zero", "stan_settings": {"init_radius": 0}},
        {**SCENARIO, "name": "seed", "stan_seed": 3},
        {**SCENARIO, "name": "elsewhere", "paper_ref": "mult_T50", "model": "sep_mult"},
    ]
    study = _study(tmp_path / "study", variants, {"zero": 18, "seed": 9, "elsewhere": 1})
    lines = variant_rows([{"folder": str(base), "scenario": "base"}], [str(study)])
    assert list(lines["scenario"]) == ["base", "zero", "seed"]  # another row's scenario left out
    assert list(lines["setup"]) == [OURS, "every chain at 0", "one Stan seed (3) for all"]
    table = variant_by_row(lines)
    assert table.columns.tolist() == ["Stan set-up", "same_a07_T100"]
    assert table.iloc[1, 1] == "0.90 [0.68, 0.99] of 20"
    assert table.iloc[-3].tolist() == ["paper", "0.808"]
    assert table.iloc[-2].tolist() == ["gradients of the row's own set-up", "autodiff"]
    # Same under its restricted prior: x0 drops out at the end a = 0, numbers kept
    assert table.iloc[-1, 0] == "edge" and "a -> 0" in table.iloc[-1, 1]
    assert "improper" not in lines.columns


IMPROPER_ROW = {  # (Sep, d=2, p=1) with b and c on (-1, 1): x0 drops out at c = 0 inside
    "name": "only_a",
    "model": "sep_d2_p1",
    "omega": {"a": 0.9, "b": 0.9, "c": 0.9},
    "x0": 8,
    "T": 50,
    "K": 40,
    "prior": {"a": "restricted", "b": "unrestricted", "c": "unrestricted"},
    "stan_every": 2,
    "paper_ref": "sep_d2_p1_a_T50",
}


def test_an_improper_rows_stan_numbers_are_not_shown(tmp_path):
    """Issue 60: no |K^Stan| of a posterior that is improper under its prior, under any
    set-up; the runs, the paper's value and the reason stay, a proper row keeps its cells."""
    base = _study(tmp_path / "row", [IMPROPER_ROW, SCENARIO], {"only_a": 13, "base": 15})
    study = _study(
        tmp_path / "study", [{**IMPROPER_ROW, "name": "seeded", "stan_seed": 1}], {"seeded": 18}
    )
    baselines = [
        {"folder": str(base), "scenario": "only_a"},
        {"folder": str(base), "scenario": "base"},
    ]
    lines = variant_rows(baselines, [str(study)]).set_index("scenario")
    assert lines.loc[["only_a", "seeded"], "K_stan"].isna().all()
    assert lines.loc[["only_a", "seeded"], "K_stan_frac_hi95"].isna().all()
    assert (lines.loc[["only_a", "seeded"], "runs"] == 20).all()
    assert lines.loc["only_a", "improper"].startswith("improper: x0 drops out")
    assert "c = 0" in lines.loc["seeded", "improper"]
    assert lines.loc["base", "improper"] == "" and lines.loc["base", "K_stan"] == 15
    table = variant_by_row(lines.reset_index()).set_index("Stan set-up")
    assert table.loc[OURS, "sep_d2_p1_a_T50"] == "not shown: improper (20 runs)"
    assert table.loc["one Stan seed (1) for all", "sep_d2_p1_a_T50"].startswith("not shown")
    assert table.loc["paper", "sep_d2_p1_a_T50"] == "0.808"
    assert table.loc["improper", "sep_d2_p1_a_T50"] == lines.loc["only_a", "improper"]
    assert table.loc["improper", "same_a07_T100"] == ""
    assert table.loc[OURS, "same_a07_T100"] == "0.75 [0.51, 0.91] of 20"
    assert not any("0.65" in cell or "0.90" in cell for cell in table["sep_d2_p1_a_T50"])
    assert "not shown: improper" in caption(lines.reset_index())
    assert "not shown" not in caption(lines.drop(columns="improper").reset_index())


def test_a_folder_that_withheld_its_count_itself_is_read(tmp_path):
    """A folder made after the propriety analysis leaves |K^Stan| of an improper row empty
    in its own summary: the table reads it and says why, as for an older folder's count."""
    base = _study(tmp_path / "row", [IMPROPER_ROW], {"only_a": float("nan")})
    lines = variant_rows([{"folder": str(base), "scenario": "only_a"}], []).set_index("scenario")
    assert pd.isna(lines.loc["only_a", "K_stan"]) and lines.loc["only_a", "runs"] == 20
    assert lines.loc["only_a", "improper"].startswith("improper: x0 drops out")
    table = variant_by_row(lines.reset_index()).set_index("Stan set-up")
    assert table.loc[OURS, "sep_d2_p1_a_T50"] == "not shown: improper (20 runs)"


def test_an_analysis_that_finds_nothing_shows_every_number(tmp_path):
    """The check reads the analysis it is given: with one that finds nothing the same
    folder shows its count, so the words above come from the analysis, not the row's name."""

    class Proper:
        improper: tuple[str, ...] = ()
        edge: tuple[str, ...] = ()
        is_improper = False

        def label(self) -> str:
            return ""

    base = _study(tmp_path / "row", [IMPROPER_ROW], {"only_a": 13})
    baselines = [{"folder": str(base), "scenario": "only_a"}]
    lines = variant_rows(baselines, [], propriety=lambda model, bounds: Proper())
    assert "improper" not in lines.columns
    assert variant_by_row(lines).iloc[0, 1] == "0.65 [0.41, 0.85] of 20"


@pytest.mark.parametrize(
    "change",
    [{"stan_every": 3}, {"K": 80}, {"x0": 7}, {"seed": 2}],
    ids=lambda c: next(iter(c)),
)
def test_a_variant_on_other_trajectories_is_refused(tmp_path, change):
    base = _study(tmp_path / "row", [SCENARIO], {"base": 15})
    other = {**SCENARIO, "name": "other", "stan_seed": 1, **change}
    study = _study(tmp_path / "study", [other], {"other": 10})
    with pytest.raises(VariantTableError, match=f"other.*{next(iter(change))}"):
        variant_rows([{"folder": str(base), "scenario": "base"}], [str(study)])


def test_a_variant_under_other_checks_is_refused(tmp_path):
    base = _study(tmp_path / "row", [SCENARIO], {"base": 15})
    study = _study(
        tmp_path / "study", [{**SCENARIO, "name": "other", "stan_seed": 1}], {"other": 3}
    )
    provenance = json.loads((study / "provenance.json").read_text())
    provenance["config"]["convergence"] = {"rhat_max": 1.05}
    (study / "provenance.json").write_text(json.dumps(provenance))
    with pytest.raises(VariantTableError, match="convergence"):
        variant_rows([{"folder": str(base), "scenario": "base"}], [str(study)])


def test_a_spec_without_its_keys_is_refused(tmp_path):
    spec = tmp_path / "spec.yaml"
    spec.write_text("output: x\nbaselines: [{folder: a}]\nstudies: []\n")
    with pytest.raises(ConfigError, match="'folder' and 'scenario'"):
        read_spec(spec)
    spec.write_text("baselines: []\nstudies: []\n")
    with pytest.raises(ConfigError, match="'output'"):
        read_spec(spec)


def test_the_committed_table_is_what_the_committed_studies_give(monkeypatch, tmp_path):
    """Regenerating the table from the committed folders gives the committed bytes: a study
    committed or replaced without `make variant-table` fails here."""
    monkeypatch.chdir(REPO_DIR)
    spec = read_spec(SPEC)
    assert all(Path(p).is_file() for p in spec_inputs(spec))
    csv, md = Path(f"{spec['output']}.csv"), Path(f"{spec['output']}.md")
    fresh_csv, fresh_md = tmp_path / "fresh.csv", tmp_path / "fresh.md"
    write_variant_table(spec, fresh_csv, fresh_md)
    assert fresh_csv.read_bytes() == csv.read_bytes(), f"{csv} is stale: make variant-table"
    assert fresh_md.read_bytes() == md.read_bytes(), f"{md} is stale: make variant-table"


def test_the_committed_table_withholds_the_improper_row(monkeypatch):
    """(Sep, d=2, p=1) with only a restricted is improper (c = 0 inside (-1, 1)): the
    committed table shows no |K^Stan|/K for it under any set-up, and the paper's 0.743."""
    monkeypatch.chdir(REPO_DIR)
    spec = read_spec(SPEC)
    lines = variant_rows(spec["baselines"], spec["studies"])
    only_a = lines[lines["row"] == "sep_d2_p1_a_T50"]
    assert len(only_a) == 10 and only_a["K_stan"].isna().all()
    assert only_a["improper"].str.contains("c = 0, inside the prior").all()
    proper = lines[lines["row"] != "sep_d2_p1_a_T50"]
    assert proper["K_stan"].notna().all() and (proper["improper"] == "").all()
    md = Path(f"{spec['output']}.md").read_text()
    assert md.count("not shown: improper") == 10 + 1  # the cells and the caption


def test_every_row_has_its_baseline_first(monkeypatch):
    monkeypatch.chdir(REPO_DIR)
    spec = read_spec(SPEC)
    lines = variant_rows(spec["baselines"], spec["studies"])
    firsts = lines.groupby("row", sort=False).head(1)
    assert (firsts["setup"] == OURS).all()
    assert len(firsts) == len(spec["baselines"])


def test_the_rules_key_follows_the_contents_of_what_it_reads(tmp_path):
    study = _study(tmp_path / "row", [SCENARIO], {"base": 15})
    inputs = [study / "provenance.json", study / "section4_summary.csv"]
    before = table_key(inputs)
    assert table_key(inputs) == before
    summary = inputs[1].read_text()
    inputs[1].write_text(summary.replace("15", "16"))
    assert table_key(inputs) != before
    inputs[1].write_text(summary)
    assert table_key(inputs) == before  # content, not mtime


def test_the_rules_key_follows_the_code_of_every_model_its_rows_name(tmp_path, monkeypatch):
    """The propriety notes read the model's terms: an edit of a row model's module (here its
    syntax digest changed) remakes the table; an edit of a model no row names does not."""
    from ssmobs import stage_code
    from ssmobs.reports import stan_variants

    study = _study(tmp_path / "row", [SCENARIO], {"base": 15})
    inputs = [study / "provenance.json", study / "section4_summary.csv"]
    assert stan_variants.row_models(inputs) == ["same"]
    before = table_key(inputs)
    digest_of = stage_code.syntax_digest

    def edited(module: str):
        def syntax_digest(path):
            return "edited" if Path(path).as_posix().endswith(module) else digest_of(path)

        return syntax_digest

    monkeypatch.setattr(stage_code, "syntax_digest", edited("models/same.py"))
    assert table_key(inputs) != before
    monkeypatch.setattr(stage_code, "syntax_digest", edited("models/sep_mult.py"))
    assert table_key(inputs) == before


def test_a_row_models_code_is_keyed_as_the_stages_key_it(monkeypatch):
    from ssmobs.cache_keys import CacheKeys
    from ssmobs.reports.stan_variants import model_code, row_models

    monkeypatch.chdir(REPO_DIR)
    models = row_models(spec_inputs(read_spec(SPEC)))
    assert models == ["same", "sep", "sep_d2_p1", "sep_mult", "sep_ranwalk"]
    keys = CacheKeys({"scenarios": [], "k_selection": []}, "native", repo=REPO_DIR)
    for model in models:
        assert model_code(model) == keys.model_code(model)
        assert f"models/{model}.py" in model_code(model)


def test_a_study_under_the_rows_own_setup_is_a_repeat_not_the_rows_cell(tmp_path):
    """Issue 63: a row regenerated with the analytic path beside a study that ran the same
    path on its trajectories: the study's line says it is the row's set-up again, the
    baseline keeps its cell, and the line of gradients names the row's own path."""
    analytic = {"stan": {"gradients": "analytic"}}
    base = _study(tmp_path / "row", [SCENARIO], {"base": 15}, extra=analytic)
    study = _study(tmp_path / "study", [{**SCENARIO, "name": "b"}], {"b": 14}, extra=analytic)
    autodiff = _study(tmp_path / "older", [{**SCENARIO, "name": "c", "stan_seed": 1}], {"c": 12})
    lines = variant_rows([{"folder": str(base), "scenario": "base"}], [str(study), str(autodiff)])
    assert list(lines["setup"]) == [
        OURS,
        "the row's own set-up, again (study)",
        "Stan's autodiff gradients, one Stan seed (1) for all",
    ]
    assert list(lines["gradients"]) == ["analytic", "analytic", "autodiff"]
    table = variant_by_row(lines).set_index("Stan set-up")
    assert table.loc[OURS, "same_a07_T100"] == "0.75 [0.51, 0.91] of 20"
    assert table.loc["the row's own set-up, again (study)", "same_a07_T100"].startswith("0.70")
    assert table.loc["gradients of the row's own set-up", "same_a07_T100"] == "analytic"


def test_two_lines_of_one_setup_in_a_row_are_refused(tmp_path):
    base = _study(tmp_path / "row", [SCENARIO], {"base": 15})
    seeded = {**SCENARIO, "name": "s", "stan_seed": 2}
    one = _study(tmp_path / "one", [seeded], {"s": 10})
    two = _study(tmp_path / "two", [seeded], {"s": 11})
    with pytest.raises(VariantTableError, match="one Stan seed .2. for all' twice"):
        variant_rows([{"folder": str(base), "scenario": "base"}], [str(one), str(two)])
