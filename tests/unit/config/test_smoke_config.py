"""`make smoke CONFIG=...`: one's own study config on the smoke profile's sizes (issue 36)."""

from __future__ import annotations

import copy
import subprocess
from pathlib import Path

import pytest
import yaml
from factories import same_a09
from repo_paths import REPO_DIR
from ssmobs.config import validation as cfg
from ssmobs.config.smoke import SMOKE_K, main, smoke_overlay

pytestmark = pytest.mark.unit
PROFILES = sorted(
    p.relative_to(REPO_DIR).as_posix()
    for p in [*(REPO_DIR / "config").glob("*.yaml"), *(REPO_DIR / "config").glob("*/*.yaml")]
    if p.name not in ("paper_values.yaml", "smoke.yaml", "stan_variants_by_row.yaml")
)


@pytest.mark.parametrize("path", PROFILES)
def test_every_profile_has_a_valid_smoke_overlay_on_small_sizes(path):
    conf = yaml.safe_load((REPO_DIR / path).read_text())
    before = copy.deepcopy(conf)
    overlay = cfg.validate(smoke_overlay(conf, Path(path).stem))
    assert conf == before  # the study's config is not changed
    assert overlay["outputs_dir"] == f"paper_figures/smoke_{Path(path).stem}"
    assert all(sc["K"] <= SMOKE_K for sc in overlay["scenarios"])
    assert all(m["K"] <= SMOKE_K for m in overlay["observability_maps"])
    assert all(max(ks["K_grid"]) <= 24 for ks in overlay["k_selection"])
    stan = overlay["stan"]
    assert (stan["chains"], stan["iter_warmup"], stan["iter_sampling"]) == (2, 300, 300)
    conv = overlay["convergence"]
    assert conv["ess_bulk_min"] == conv["ess_tail_min"] == 200  # 100 x chains
    # what is studied stays: models, true values, horizons, the studies and maps
    for mine, theirs in zip(overlay["scenarios"], before["scenarios"]):
        assert {k: mine[k] for k in ("name", "model", "omega", "x0", "T")} == {
            k: theirs[k] for k in ("name", "model", "omega", "x0", "T")
        }
    assert len(overlay["observability_studies"]) == len(before.get("observability_studies", []))


def test_scenario_settings_follow_the_smaller_K():
    conf = {
        "scenarios": [
            same_a09(
                K=50, exact_K=500, stan_every=10, stan_settings={"chains": 4, "adapt_delta": 0.9}
            )
        ],
        "stan": {"keep_draws": [0, 3, 10], "chains": 4},
        "convergence": {"ess_bulk_min": 150},
    }
    overlay = cfg.validate(smoke_overlay(conf, "mine"))
    (sc,) = overlay["scenarios"]
    assert (sc["K"], sc["exact_K"], sc["stan_every"]) == (4, 4, 4)
    assert sc["stan_settings"] == {"chains": 2, "adapt_delta": 0.9}
    assert overlay["stan"]["keep_draws"] == [0, 3]
    # a minimum already below 100 x chains stays
    assert overlay["convergence"]["ess_bulk_min"] == 150
    assert overlay["convergence"]["ess_tail_min"] == 200


def test_the_overlay_file_and_the_make_recipe(tmp_path, capsys):
    out = tmp_path / "results" / "smoke_configs" / "stoch_vol.yaml"
    assert main([str(REPO_DIR / "config" / "stoch_vol.yaml"), "--out", str(out)]) == 0
    assert "paper_figures/smoke_stoch_vol/" in capsys.readouterr().out
    text = out.read_text()
    assert text.startswith("# Made by `make smoke CONFIG=")
    assert cfg.validate(yaml.safe_load(text))["outputs_dir"] == "paper_figures/smoke_stoch_vol"
    # a bad study config is named, and nothing is written
    bad = tmp_path / "bad.yaml"
    bad.write_text("scenarios:\n  - {name: s, model: nope, omega: {a: 0.9}, x0: 8, T: 4, K: 4}\n")
    assert main([str(bad), "--out", str(tmp_path / "bad_overlay.yaml")]) == 1
    err = capsys.readouterr().err
    assert f"config file {bad} (at the smoke profile's sizes)" in err and "unknown model" in err
    assert not (tmp_path / "bad_overlay.yaml").exists()
    # the make target: the overlay, its preflight and Snakemake on it (printed, not run)
    plan = subprocess.run(
        ["make", "--no-print-directory", "-n", "smoke", "CONFIG=config/stoch_vol.yaml"],
        cwd=REPO_DIR,
        capture_output=True,
        text=True,
        check=True,
    ).stdout.splitlines()
    assert plan[-3:] == [
        ".venv/bin/python -m ssmobs.config.smoke config/stoch_vol.yaml "
        "--out results/smoke_configs/stoch_vol.yaml",
        ".venv/bin/python -m ssmobs.config.preflight --unlock-stale "
        "results/smoke_configs/stoch_vol.yaml",
        ".venv/bin/snakemake --cores 2 --rerun-incomplete "
        "--configfile results/smoke_configs/stoch_vol.yaml",
    ]
