"""Helpers shared by the workflow tests: copy the workflow, run and interrupt Snakemake."""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import yaml

REPO = Path(__file__).resolve().parents[2]
COPY = ["Snakefile", "workflow", "config", "stan", "envs", "profiles"]


def make_workdir(dest: Path) -> Path:
    """A copy of the workflow in ``dest`` (so runs never write into the repository)."""
    dest.mkdir(parents=True, exist_ok=True)
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
#: where the smoke profile writes its tables and figures (its outputs_dir)
SMOKE_OUT = "paper_figures/smoke"


def only(workdir: Path, pattern: str) -> Path:
    """The one file matching ``pattern`` under ``workdir`` (results are keyed: in a run of
    one config each stage of a scenario has one key folder)."""
    found = sorted(workdir.glob(pattern))
    assert len(found) == 1, f"{pattern}: expected one match, found {[str(f) for f in found]}"
    return found[0]


def slurm_profile_dry_run(*args: str, workdir: Path | None = None) -> subprocess.CompletedProcess:
    """`snakemake -n` with the SLURM profile and a placeholder account and partition (what a
    user adds on the command line); stdout + stderr as text.  In ``workdir``, by default a
    fresh copy of the workflow: what a run left in the checkout's results/ must not matter."""
    import tempfile

    if workdir is None:
        workdir = make_workdir(Path(tempfile.mkdtemp(prefix="ssmobs_dry_run_")))
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
        cwd=workdir,
        capture_output=True,
        text=True,
        timeout=600,
    )


# --- The jobs Snakemake prints: the plan of a dry run, and what a real run started ---------------

_GROUP_HEADER = re.compile(r"Group job (\S+) \(jobs in lexicogr\. order\):$")
_JOB_HEADER = re.compile(r"^(\s*)(local)?(?:rule|checkpoint) (\w+):$")
_JOB_FIELD = re.compile(r"^\s+(jobid|input|output): (.*)$")


@dataclass
class LoggedJob:
    """One job as Snakemake prints it (`rule x:` and its indented fields)."""

    rule: str
    local: bool  # printed as `localrule x:`: ran on the submitting host (never so in a dry run)
    jobid: str = ""
    input: tuple[str, ...] = ()
    output: tuple[str, ...] = ()


@dataclass
class LoggedUnit:
    """What Snakemake schedules as one: a group job (`group` its id) or a job of its own."""

    group: str | None
    jobs: list[LoggedJob] = field(default_factory=list)


def logged_units(text: str) -> list[LoggedUnit]:
    """The jobs in Snakemake's output (a `--dry-run`, or a run's log), in order of printing.

    A job is a `rule x:` (`localrule x:` when it ran locally) line at the start of a line with
    indented `input:`, `output:`, `jobid:` fields; `Group job g (jobs in lexicogr. order):` is
    followed by its member jobs, each indented one level. Other lines are ignored.
    """
    units: list[LoggedUnit] = []
    group: LoggedUnit | None = None  # the group job whose members are being printed
    job: LoggedJob | None = None  # the job whose fields are being printed
    for line in text.splitlines():
        if m := _GROUP_HEADER.search(line):
            group = LoggedUnit(m.group(1))
            units.append(group)
            job = None
        elif m := _JOB_HEADER.match(line):
            indent, local, rule = m.groups()
            job = LoggedJob(rule, local=bool(local))
            if not indent:
                group = None
                units.append(LoggedUnit(None, [job]))
            elif group is not None:
                group.jobs.append(job)
            else:
                raise ValueError(f"an indented job outside a group job: {line!r}")
        elif job is not None and (m := _JOB_FIELD.match(line)):
            key, value = m.groups()
            if key == "jobid":
                job.jobid = value.strip()
            else:
                setattr(job, key, tuple(f.strip() for f in value.split(", ")))
        elif line and not line[0].isspace():
            job = None  # `Shell command: ...`, a message: the job's fields are over
    return units


def local_rules(workdir: Path, *configfiles: str) -> set[str]:
    """The rules whose jobs Snakemake runs on the submitting host even with a cluster executor:
    `localrules:` and `localrule: True`, rules without anything to run (`all`) and template
    rules, unless grouped (Snakemake's `Workflow.is_local` with a non-local executor)."""
    script = """
import json, sys
from pathlib import Path
from snakemake.api import SnakemakeApi
from snakemake.settings.types import (
    ConfigSettings, OutputSettings, ResourceSettings, StorageSettings)
with SnakemakeApi(OutputSettings()) as api:
    wf = api.workflow(
        ResourceSettings(),
        ConfigSettings(configfiles=[Path(f).absolute() for f in sys.argv[1:]]),
        StorageSettings(),
        snakefile=Path("Snakefile").absolute(),
        workdir=Path(".").absolute(),
    )._workflow
    rules = [r.name for r in wf.rules
             if r.group is None and (r.name in wf._localrules or r.norun or r.is_template_engine)]
    print("LOCAL_RULES " + json.dumps(rules))
"""
    proc = subprocess.run(
        [sys.executable, "-c", script, *configfiles],
        cwd=workdir,
        capture_output=True,
        text=True,
        timeout=600,
    )
    lines = [line for line in proc.stdout.splitlines() if line.startswith("LOCAL_RULES ")]
    if proc.returncode != 0 or not lines:
        raise AssertionError(f"could not list the local rules:\n{proc.stdout}\n{proc.stderr}")
    return set(json.loads(lines[-1].split(" ", 1)[1]))
