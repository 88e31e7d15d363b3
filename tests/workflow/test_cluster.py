"""Issue 10: the smoke profile on a real SLURM cluster through the executor plugin.

Runs where `sinfo` reaches a cluster with a node ready for jobs (CI starts a one-node cluster
with .ci/start_slurm.sh); skips with the reason otherwise. Not a dry run: every job is submitted
with sbatch, and the tables must be byte-identical to the local `--cores 2` run of the same
profile (the `smoke_run` fixture).
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from helpers import SMOKE, make_workdir, slurm_profile_dry_run, snakemake

pytestmark = pytest.mark.workflow

TABLE_SUFFIXES = (".csv", ".md", ".tex")
READY_STATES = {"idle", "mixed", "allocated", "completing"}


def cluster_unavailable() -> str | None:
    """Why no SLURM cluster can take jobs here, or None when one can."""
    if shutil.which("sinfo") is None:
        return "no SLURM client on PATH (sinfo); start one with .ci/start_slurm.sh"
    try:
        proc = subprocess.run(
            ["sinfo", "--noheader", "--format=%P %a %T"], capture_output=True, text=True, timeout=30
        )
    except subprocess.TimeoutExpired:
        return "sinfo did not answer within 30 s"
    if proc.returncode != 0:
        return f"sinfo failed: {proc.stderr.strip()[:300]}"
    ready = [
        line.split()
        for line in proc.stdout.splitlines()
        if len(line.split()) == 3
        and line.split()[1] == "up"
        and line.split()[2].rstrip("*~#!%$@^-") in READY_STATES
    ]
    if not ready:
        return f"no partition with a node ready for jobs: {proc.stdout.strip()[:300]!r}"
    return None


def tables(workdir: Path) -> dict[str, bytes]:
    return {
        f.name: f.read_bytes()
        for f in sorted((workdir / "paper_figures").iterdir())
        if f.suffix in TABLE_SUFFIXES
    }


@pytest.fixture(scope="module")
def cluster_run(tmp_path_factory) -> tuple[Path, str]:
    """The smoke profile submitted to SLURM with the repository's cluster profile."""
    reason = cluster_unavailable()
    if reason:
        pytest.skip(f"no SLURM cluster: {reason}")
    workdir = make_workdir(tmp_path_factory.mktemp("cluster"))
    env = dict(os.environ)
    # Jobs inherit this environment (sbatch --export=ALL): this interpreter's bin first on PATH,
    # and the package under test importable even where it is not installed.
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}"
    env["PYTHONPATH"] = os.pathsep.join(
        p for p in [str(workdir / "workflow"), env.get("PYTHONPATH", "")] if p
    )
    proc = snakemake(
        workdir,
        "--workflow-profile",
        "config/profiles/slurm",
        *SMOKE,
        # no accounting database on the CI cluster: job states from squeue
        "--slurm-status-command",
        "squeue",
        "--slurm-init-seconds-before-status-checks",
        "5",
        "--seconds-between-status-checks",
        "5",
        "--slurm-keep-successful-logs",
        timeout=3600,
        env=env,
    )
    return workdir, proc.stdout + proc.stderr


def test_profile_sets_runtime_and_memory_of_every_job():
    """Account and partition on the command line replace the profile's default-resources
    whole; every submitted job must still get a time limit and a memory request."""
    proc = slurm_profile_dry_run(*SMOKE)
    assert proc.returncode == 0, proc.stderr[-3000:]
    jobs = re.findall(r"rule (\w+):\n(?:.*\n)*?\s+resources: (.*)", proc.stdout + proc.stderr)
    rules = {rule for rule, _ in jobs} - {"all"}
    assert "sample_nuts" in rules and len(rules) >= 10
    for rule, resources in jobs:
        if rule != "all":
            assert re.search(r"\bruntime=\d+", resources), (rule, resources)
            assert re.search(r"\bmem_mb=\d+", resources), (rule, resources)
            assert "slurm_account=acct" in resources and "slurm_partition=part" in resources


@pytest.mark.cluster
@pytest.mark.slow
def test_every_job_went_through_slurm(cluster_run):
    workdir, log = cluster_run
    submitted = re.findall(r"submitted with SLURM jobid (\d+)", log)
    assert submitted, log[-3000:]
    # the Stan batches ran as group jobs (`group: nuts`), each one submission
    assert list((workdir / ".snakemake" / "slurm_logs").glob("group_nuts*")), log[-3000:]
    for job_log in (workdir / ".snakemake" / "slurm_logs").rglob("*.log"):
        assert "Error" not in job_log.read_text(errors="replace"), job_log


@pytest.mark.cluster
@pytest.mark.slow
def test_tables_identical_to_local_run(cluster_run, smoke_run):
    workdir, _ = cluster_run
    ours, local = tables(workdir), tables(smoke_run)
    assert len(local) >= 12 and set(ours) == set(local)
    differ = [name for name in local if ours[name] != local[name]]
    assert not differ, f"tables differ between the SLURM and the local run: {differ}"
