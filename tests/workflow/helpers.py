"""Helpers shared by the workflow tests: copy the workflow, run and interrupt Snakemake."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import yaml

REPO = Path(__file__).resolve().parents[2]
COPY = ["Snakefile", "workflow", "config", "stan", "envs"]


def make_workdir(dest: Path) -> Path:
    """A copy of the workflow in ``dest`` (so runs never write into the repository)."""
    for name in COPY:
        src = REPO / name
        if src.is_dir():
            shutil.copytree(
                src, dest / name, ignore=shutil.ignore_patterns("__pycache__", "*.egg-info")
            )
        else:
            shutil.copy2(src, dest / name)
    return dest


def snakemake(
    workdir: Path,
    *args: str,
    check: bool = True,
    timeout: int = 1800,
    env: dict[str, str] | None = None,
) -> subprocess.CompletedProcess:
    cmd = [sys.executable, "-m", "snakemake", *args]
    proc = subprocess.run(
        cmd, cwd=workdir, capture_output=True, text=True, timeout=timeout, env=env
    )
    if check and proc.returncode != 0:
        raise AssertionError(
            f"{' '.join(cmd)} failed ({proc.returncode}):\n"
            f"{proc.stdout[-3000:]}\n{proc.stderr[-6000:]}"
        )
    return proc


def kill_when(workdir: Path, args: list[str], ready, timeout: float = 900) -> None:
    """Start Snakemake, wait until ``ready(workdir)`` is true, then SIGKILL its process group."""
    cmd = [sys.executable, "-m", "snakemake", *args]
    proc = subprocess.Popen(
        cmd,
        cwd=workdir,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )
    start = time.monotonic()
    try:
        while time.monotonic() - start < timeout:
            if proc.poll() is not None:
                raise AssertionError("the workflow finished before it could be interrupted")
            if ready(workdir):
                break
            time.sleep(0.05)
        else:
            raise AssertionError("timed out waiting for the moment to interrupt")
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()


def smoke_config() -> dict:
    return yaml.safe_load((REPO / "config" / "smoke.yaml").read_text())


SMOKE = ["--configfile", "config/smoke.yaml"]


def slurm_profile_dry_run(*args: str) -> subprocess.CompletedProcess:
    """`snakemake -n` in the repository with the SLURM profile and a placeholder account and
    partition (what a user adds on the command line); stdout + stderr as text."""
    return subprocess.run(
        [
            sys.executable,
            "-m",
            "snakemake",
            "-n",
            "--workflow-profile",
            "config/profiles/slurm",
            *args,
            "--default-resources",
            "slurm_account=acct",
            "slurm_partition=part",
        ],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=600,
    )
