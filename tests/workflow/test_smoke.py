"""The workflow end to end on config/smoke.yaml, in a temporary directory."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
import yaml
from helpers import REPO, SMOKE_OUT, make_workdir, only, smoke_config, snakemake

pytestmark = pytest.mark.workflow


def test_design_trajectories_written(smoke_run):
    from ssmobs.design.trajectories import read_trajectories

    for sc in smoke_config()["scenarios"]:
        traj = read_trajectories(
            only(smoke_run, f"results/{sc['name']}/design_trajectories/*/trajectories.nc")
        )
        assert traj.K == sc["K"] and traj.T == sc["T"]
        assert np.all(np.isfinite(traj.x)) and np.all(np.isfinite(traj.z))


def test_design_disturbances_cached_and_valid(smoke_run):
    from ssmobs import io

    files = sorted(smoke_run.glob("results/shared/design_disturbances/*/*.nc"))
    assert files, "no disturbance files"
    for f in files:
        matrix, attrs = io.read_disturbances(f)
        assert matrix.shape == (attrs["q"], attrs["K"])
        if attrs["method"] == "design":
            # point symmetric: the mean is exactly zero
            np.testing.assert_allclose(matrix.mean(axis=1), 0.0, atol=1e-12)


def test_figure2_written(smoke_run):
    for ext in ("pdf", "png"):
        f = smoke_run / SMOKE_OUT / f"fig2_design_points.{ext}"
        assert f.stat().st_size > 1000


def test_rerun_does_nothing(smoke_run):
    proc = snakemake(smoke_run, "--cores", "1", "--configfile", "config/smoke.yaml", "-n")
    assert "Nothing to be done" in proc.stdout + proc.stderr


def test_lint_passes():
    proc = subprocess.run(
        [sys.executable, "-m", "snakemake", "--lint", "--cores", "1"],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    assert "Lints for" not in proc.stdout + proc.stderr, proc.stdout + proc.stderr


@pytest.mark.parametrize(
    "profile",
    [
        "config/config.yaml",
        # the paper profile (about 74 CPU-hours, run rarely): its dry run in test-slow (issue 48)
        pytest.param("config/paper.yaml", marks=pytest.mark.slow),
    ],
)
def test_dry_run_profiles(profile):
    proc = subprocess.run(
        [sys.executable, "-m", "snakemake", "-n", "--cores", "2", "--configfile", profile],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]


def test_bad_config_stops_before_any_work(tmp_path):
    workdir = make_workdir(tmp_path)
    bad = smoke_config()
    bad["scenarios"][0]["K"] = 0
    (workdir / "bad.yaml").write_text(yaml.safe_dump(bad))
    proc = snakemake(workdir, "--cores", "1", "--configfile", "bad.yaml", check=False)
    assert proc.returncode != 0
    out = proc.stdout + proc.stderr
    assert "scenarios[0].K = 0: must be >= 1" in out
    assert not (workdir / "results").exists()


@pytest.mark.stan
@pytest.mark.slow  # a PyStan build and two more smoke runs: about 4 minutes
def test_pystan_backend_gives_the_same_tables(tmp_path):
    """The smoke workflow on PyStan reproduces the native backend's tables byte for byte
    (the backends give identical draws of the same program: the hand-written one, as PyStan
    takes no generated C++), and every record is recomputed for it."""
    runs = {}
    for backend in ("native", "pystan"):
        conf = smoke_config()
        conf["stan"].update(backend=backend, gradients="autodiff")
        workdir = make_workdir(tmp_path / backend)
        (workdir / "config" / "smoke_backend.yaml").write_text(yaml.safe_dump(conf))
        snakemake(workdir, "--cores", "2", "--configfile", "config/smoke_backend.yaml")
        runs[backend] = workdir
        rec = next(only(workdir, "results/same_T4/sample_nuts/records/*").glob("*.json"))
        assert yaml.safe_load(rec.read_text())["key"]["backend"].startswith(backend)
    tables = ["table2_joint_vs_marginal.csv", "table3_coverage.csv", "section4_summary.csv"]
    for name in tables:
        assert (runs["pystan"] / SMOKE_OUT / name).read_bytes() == (
            runs["native"] / SMOKE_OUT / name
        ).read_bytes(), name


def test_every_model_was_checked_before_its_trajectories(smoke_run):
    from ssmobs import io

    for sc in smoke_config()["scenarios"]:
        report = io.read_json(only(smoke_run, f"results/{sc['name']}/check_model/*.json"))
        assert report["ok"] and report["problems"] == []
        assert not any("stan compiled" in c for c in report["checks"])
        stan_checks = list(smoke_run.glob(f"results/{sc['name']}/check_model_stan/*.json"))
        assert len(stan_checks) == int(sc.get("stan", True))
        for check in stan_checks:
            assert any("stan compiled" in c for c in io.read_json(check)["checks"])


def test_own_model_observability_study_written(smoke_run):
    import pandas as pd

    frame = pd.read_csv(smoke_run / SMOKE_OUT / "ours_stoch_vol_observability.csv")
    assert frame["scenario"].tolist() == ["stoch_vol_T5"]
    assert frame["K"].tolist() == [4]
    for col in ("K_max_ratio", "K_stan_ratio"):
        assert 0.0 <= frame[col].iloc[0] <= 1.0
    assert (smoke_run / SMOKE_OUT / "ours_stoch_vol_observability.png").stat().st_size > 1000
    assert "|K^max|/K" in (smoke_run / SMOKE_OUT / "ours_stoch_vol_observability.md").read_text()


def test_step_quick_run_on_smoke_profile(smoke_run):
    """docs/your-own-model.md, its quick run: `make smoke` (the session's smoke run) writes
    the study's table beside the others (the tutorial's other steps: test_own_model.py)."""
    import pandas as pd

    frame = pd.read_csv(smoke_run / SMOKE_OUT / "ours_stoch_vol_observability.csv")
    assert frame["T"].tolist() == [5]
    assert {"K_max_ratio", "K_stan_ratio", "joint_not_ok", "stan_failed_checks"} <= set(frame)
    assert list(smoke_run.glob("results/stoch_vol_T5/check_model/*.json"))
