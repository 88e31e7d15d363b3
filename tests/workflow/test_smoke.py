"""The workflow end to end on config/smoke.yaml, in a temporary directory."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from conftest import REPO

pytestmark = pytest.mark.workflow

COPY = ["Snakefile", "workflow", "config", "stan", "envs"]


def make_workdir(dest: Path) -> Path:
    for name in COPY:
        src = REPO / name
        if src.is_dir():
            shutil.copytree(src, dest / name, ignore=shutil.ignore_patterns("__pycache__", "*.egg-info"))
        else:
            shutil.copy2(src, dest / name)
    return dest


def snakemake(workdir: Path, *args: str, check: bool = True, timeout: int = 1800) -> subprocess.CompletedProcess:
    cmd = [sys.executable, "-m", "snakemake", *args]
    proc = subprocess.run(cmd, cwd=workdir, capture_output=True, text=True, timeout=timeout)
    if check and proc.returncode != 0:
        raise AssertionError(f"{' '.join(cmd)} failed ({proc.returncode}):\n{proc.stdout[-3000:]}\n"
                             f"{proc.stderr[-6000:]}")
    return proc


@pytest.fixture(scope="session")
def smoke_run(tmp_path_factory) -> Path:
    workdir = make_workdir(tmp_path_factory.mktemp("smoke"))
    snakemake(workdir, "--cores", "2", "--configfile", "config/smoke.yaml")
    return workdir


def smoke_config() -> dict:
    return yaml.safe_load((REPO / "config" / "smoke.yaml").read_text())


def test_design_trajectories_written(smoke_run):
    from ssmobs.trajectories import read_trajectories

    for sc in smoke_config()["scenarios"]:
        traj = read_trajectories(smoke_run / "results" / sc["name"] / "design_trajectories" / "trajectories.nc")
        assert traj.K == sc["K"] and traj.T == sc["T"]
        assert np.all(np.isfinite(traj.x)) and np.all(np.isfinite(traj.z))


def test_design_disturbances_cached_and_valid(smoke_run):
    from ssmobs import io

    files = sorted((smoke_run / "results" / "shared" / "design_disturbances").glob("*.nc"))
    assert files, "no disturbance files"
    for f in files:
        matrix, attrs = io.read_disturbances(f)
        assert matrix.shape == (attrs["q"], attrs["K"])
        if attrs["method"] == "design":
            # point symmetric: the mean is exactly zero
            np.testing.assert_allclose(matrix.mean(axis=1), 0.0, atol=1e-12)


def test_figure2_written(smoke_run):
    for ext in ("pdf", "png"):
        f = smoke_run / "paper_figures" / f"fig2_design_points.{ext}"
        assert f.stat().st_size > 1000


def test_rerun_does_nothing(smoke_run):
    proc = snakemake(smoke_run, "--cores", "1", "--configfile", "config/smoke.yaml", "-n")
    assert "Nothing to be done" in proc.stdout + proc.stderr


def test_lint_passes():
    proc = subprocess.run([sys.executable, "-m", "snakemake", "--lint", "--cores", "1"], cwd=REPO,
                          capture_output=True, text=True, timeout=300)
    assert "Lints for" not in proc.stdout + proc.stderr, proc.stdout + proc.stderr


@pytest.mark.parametrize("profile", ["config/config.yaml", "config/paper.yaml"])
def test_dry_run_profiles(profile):
    proc = subprocess.run([sys.executable, "-m", "snakemake", "-n", "--cores", "2", "--configfile", profile],
                          cwd=REPO, capture_output=True, text=True, timeout=300)
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
