"""Issues 60 and 61 through Snakemake itself (dry runs in a copy of the workflow): a number
on ``--config`` that YAML 1.1 and 1.2 read differently stops the run in one line naming the
key, a plain one is planned as written, and a prior interval with ``.inf`` passes."""

from __future__ import annotations

import re

import pytest
from helpers import make_workdir, snakemake

pytestmark = pytest.mark.workflow


def dry_run(workdir, *args: str):
    return snakemake(
        workdir, "-n", "--cores", "1", "--configfile", "config/smoke.yaml", *args, check=False
    )


def test_numbers_on_the_command_line_and_infinite_prior_bounds(tmp_path):
    workdir = make_workdir(tmp_path / "wd")
    refused = dry_run(workdir, "--config", "figure2={a: 0.9, x0: 8, K: 010, seed: 0}")
    assert refused.returncode != 0
    assert (
        "figure2.K = '010': a number with a leading zero, which YAML 1.1 reads as 8 and "
        "YAML 1.2 as 10; allowed: a number in plain decimal digits"
        in refused.stdout
        + refused.stderr
    )
    planned = dry_run(workdir, "--config", 'figure2={a: 0.9, x0: 8, K: "10", seed: 0}')
    assert planned.returncode == 0, planned.stderr[-3000:]
    assert set(re.findall(r"q2_K\d+_design", planned.stdout)) == {"q2_K10_design"}
    smoke = (workdir / "config" / "smoke.yaml").read_text()
    own = "joint_map_n_starts: 4}"
    assert own in smoke  # the stoch_vol scenario and map base of the smoke profile
    (workdir / "config" / "inf.yaml").write_text(
        smoke.replace(own, "joint_map_n_starts: 4, prior: {phi: [-1, 1], sigma: [0, .inf]}}")
    )
    proc = snakemake(workdir, "-n", "--cores", "1", "--configfile", "config/inf.yaml", check=False)
    assert proc.returncode == 0, proc.stderr[-3000:]
