"""`make paper` samples with the analytic gradients (issue 63, item 1): the profile sets
``stan.gradients: analytic`` and every model it samples has a generated program (so no
model silently falls back to Stan's autodiff or is refused at its first Stan job)."""

from __future__ import annotations

import pytest
from repo_paths import REPO_DIR
from ssmobs.config.validation import read_config_file
from ssmobs.nuts.stan_program import stan_program

pytestmark = pytest.mark.unit

PAPER = REPO_DIR / "config" / "paper.yaml"


def test_the_paper_profile_samples_every_model_with_generated_gradients():
    config = read_config_file(PAPER)
    assert config["stan"]["gradients"] == "analytic"
    models = sorted(
        {sc["model"] for sc in config["scenarios"] if sc.get("stan", True) is not False}
    )
    assert len(models) == 6
    for model in models:
        program, header = stan_program(model, config["stan"]["gradients"])
        assert header is not None and header.is_file(), model
        assert f"{model}_analytic" in program.name and program.is_file()
