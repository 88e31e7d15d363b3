"""Issue 10: the smoke profile on a real SLURM cluster through the executor plugin.

Runs where `sinfo` reaches a cluster with a node ready for jobs (CI starts a one-node cluster
with .ci/start_slurm.sh); skips with the reason otherwise, or fails when SSMOBS_REQUIRE_CLUSTER=1
(.ci/run sets it: CI must not pass without this test). Not a dry run: every job that is not a
local rule is submitted with sbatch, one submission per planned job or group job (counted
against the dry run of the same command), and the tables must be byte-identical to the local
`--cores 2` run of the same profile (the `smoke_run` fixture).
"""

from __future__ import annotations

import math
import os
import re
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest
import yaml
from helpers import (
    REPO,
    SMOKE,
    LoggedJob,
    LoggedUnit,
    local_rules,
    logged_units,
    make_workdir,
    slurm_profile_dry_run,
    smoke_config,
    snakemake,
)

pytestmark = pytest.mark.workflow

TABLE_SUFFIXES = (".csv", ".md", ".tex")
READY_STATES = {"idle", "mixed", "allocated", "completing"}
PROFILE = "config/profiles/slurm"
# The smoke profile's Stan jobs are short: as the SLURM profile advises for such profiles, pack
# this many of them (connected components of a group) into one submission, so the count of
# submissions also covers group jobs holding several jobs.
PACK = 3
# the executor plugin's line for every sbatch call (a group job's Snakemake id is a UUID)
SUBMITTED = re.compile(r"^Job (\S+) has been submitted with SLURM jobid (\d+)", re.MULTILINE)


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
    """The smoke profile's tables (in its `outputs_dir`)."""
    out = workdir / smoke_config().get("outputs_dir", "paper_figures")
    return {f.name: f.read_bytes() for f in sorted(out.iterdir()) if f.suffix in TABLE_SUFFIXES}


def group_settings() -> dict[str, int]:
    """Connected components per group job, by group id: the profile's `group-components` with
    every group of the profile's `groups` set to PACK (the command line below)."""
    profile = yaml.safe_load((REPO / PROFILE / "config.yaml").read_text())
    settings = {str(g): int(n) for g, n in (profile.get("group-components") or {}).items()}
    settings.update({str(g): PACK for g in (profile.get("groups") or {}).values()})
    return settings


def group_components_args() -> list[str]:
    return ["--group-components", *(f"{g}={n}" for g, n in group_settings().items())]


def runs_locally(unit: LoggedUnit, local: set[str]) -> bool:
    """Whether Snakemake runs this on the submitting host: a job of a local rule (a group job
    never is)."""
    return unit.group is None and unit.jobs[0].rule in local


def connected_components(jobs) -> int:
    """How many connected components the jobs form (edges: one job's output is another's input)."""
    parent = list(range(len(jobs)))

    def root(i: int) -> int:
        while parent[i] != i:
            i = parent[i]
        return i

    for i, a in enumerate(jobs):
        for j, b in enumerate(jobs):
            if set(a.output) & set(b.input):
                parent[root(i)] = root(j)
    return len({root(i) for i in range(len(jobs))})


def expected_submissions(plan: list[LoggedUnit], local: set[str]) -> list[LoggedUnit]:
    """The sbatch calls the plan (a dry run's jobs) asks for: every group job and every job of a
    rule that is not local. Checks first that the plan's group jobs are what the group settings
    make of the grouped jobs: ceil(connected components / components per group job)."""
    settings = group_settings()
    for group in {u.group for u in plan if u.group is not None}:
        units = [u for u in plan if u.group == group]
        components = connected_components([j for u in units for j in u.jobs])
        assert len(units) == math.ceil(components / settings.get(group, 1)), (
            group,
            [len(u.jobs) for u in units],
            components,
        )
    return [u for u in plan if not runs_locally(u, local)]


@dataclass
class ClusterRun:
    workdir: Path
    plan: str  # the dry run of the same command: its jobs are the plan
    log: str  # the run's stdout and stderr
    local_rules: set[str]


@pytest.fixture(scope="module")
def cluster_run(tmp_path_factory) -> ClusterRun:
    """The smoke profile submitted to SLURM with the repository's cluster profile."""
    reason = cluster_unavailable()
    if reason:
        if os.environ.get("SSMOBS_REQUIRE_CLUSTER") == "1":
            pytest.fail(
                f"no SLURM cluster, but SSMOBS_REQUIRE_CLUSTER=1 requires one: {reason}",
                pytrace=False,
            )
        pytest.skip(f"no SLURM cluster: {reason}")
    workdir = make_workdir(tmp_path_factory.mktemp("cluster"))
    env = dict(os.environ)
    # Jobs inherit this environment (sbatch --export=ALL): this interpreter's bin first on PATH,
    # and the package under test importable even where it is not installed.
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}"
    env["PYTHONPATH"] = os.pathsep.join(
        p for p in [str(workdir / "workflow"), env.get("PYTHONPATH", "")] if p
    )
    # submitted from a shell with the machine's own kernels and four BLAS threads: the jobs
    # must still compute with the fixed ones (test_slurm_jobs_compute_with_the_local_kernels)
    for name in ("OPENBLAS_CORETYPE", "NPY_DISABLE_CPU_FEATURES"):
        env.pop(name, None)
    env["OPENBLAS_NUM_THREADS"] = "4"
    args = ["--workflow-profile", PROFILE, *SMOKE, *group_components_args()]
    dry = snakemake(workdir, "--dry-run", *args, env=env)
    proc = snakemake(
        workdir,
        *args,
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
    return ClusterRun(
        workdir,
        plan=dry.stdout + dry.stderr,
        log=proc.stdout + proc.stderr,
        local_rules=local_rules(workdir, *SMOKE[1:]),
    )


@pytest.mark.slow  # a dry run through the SLURM profile (a rare path): test-slow (issue 48)
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


# Snakemake 9.27's output, captured (paths and lines shortened, most jobs left out): a dry run of
# the smoke profile with `--group-components nuts=4`, and the log of its run on SLURM.
DRY_RUN_SAMPLE = """\
Building DAG of jobs...
Job stats:
job                         count
------------------------  -------
build_stan_model                3
total                          80


[Tue Dec  1 17:09:57 2026]
rule build_stan_model:
    input: /tmp/dr/stan/stoch_vol.stan
    output: results/shared/stan/native/stoch_vol.json
    log: results/shared/logs/build_stan_model/native/stoch_vol.log
    jobid: 28
    reason: Missing output files: results/shared/stan/native/stoch_vol.json
    wildcards: backend=native, model=stoch_vol
    resources: tmpdir=/tmp, disk_mb=1000, mem_mb=4000, mem=4 GB, runtime=30
Shell command: None

[Tue Dec  1 17:09:57 2026] Group job nuts (jobs in lexicogr. order):

    [Tue Dec  1 17:09:57 2026]
    rule sample_nuts:
        input: results/ranwalk_T4/design_trajectories/trajectories.nc, results/shared/stan/x.json
        output: results/ranwalk_T4/sample_nuts/batch0.parquet
        log: results/ranwalk_T4/logs/sample_nuts/batch0.log
        jobid: 23
        wildcards: scenario=ranwalk_T4, batch=0
        resources: tmpdir=/tmp, disk_mb=<TBD>, mem_mb=3000, mem=3 GB, runtime=120
Shell command: None

    [Tue Dec  1 17:09:57 2026]
    rule sample_nuts:
        input: results/same_T4/design_trajectories/trajectories.nc, results/shared/stan/y.json
        output: results/same_T4/sample_nuts/batch2.parquet
        log: results/same_T4/logs/sample_nuts/batch2.log
        jobid: 21
        wildcards: scenario=same_T4, batch=2
        resources: tmpdir=/tmp, disk_mb=<TBD>, mem_mb=3000, mem=3 GB, runtime=120
Shell command: None

[Tue Dec  1 17:09:57 2026]
rule figure_exact_vs_stan:
    input: results/same_T4/gather_nuts/marginal_map.parquet
    output: paper_figures/fig_exact_vs_stan_same_T4.pdf, paper_figures/fig_exact_vs_stan_same_T4.png
    log: results/same_T4/logs/figure_exact_vs_stan.log
    jobid: 70
    wildcards: scenario=same_T4
    resources: tmpdir=/tmp, disk_mb=<TBD>, mem_mb=2000, mem=2 GB, runtime=10
Shell command: None

[Tue Dec  1 17:09:57 2026]
rule all:
    input: results/same_T4/design_trajectories/trajectories.nc, paper_figures/table3_coverage.tex
    jobid: 0
    reason: Input files updated by another job: paper_figures/table3_coverage.tex
    resources: tmpdir=/tmp, disk_mb=<TBD>, mem_mb=2000, mem=2 GB, runtime=30
Shell command: None
Job stats:
job                         count
------------------------  -------
all                             1
total                          80

Reasons:
    (check individual jobs above for details)
    input files updated by another job:
        all, sample_nuts
    output files have to be generated:
        build_stan_model, sample_nuts
This was a dry-run (flag -n). The order of jobs does not reflect the order of execution.
"""
RUN_LOG_SAMPLE = """\
Select jobs to execute...
Execute 1 jobs...
[Tue Dec  1 17:37:08 2026]
localrule select_k:
    input: results/k_selection/same_T4/design_independent_seed1/K8.json, config/paper_values.yaml
    output: results/k_selection/same_T4/selection.json, results/k_selection/same_T4/v_vectors.csv
    log: results/k_selection/same_T4/logs/select_k.log
    jobid: 29
    wildcards: ksel=same_T4
    resources: tmpdir=/tmp, mem_mb=2000, mem=2 GB, mem_mib=1908, disk_mb=1000, runtime=10
Shell command: None
[Tue Dec  1 17:37:46 2026]
Finished jobid: 66 (Rule: table_k_selection)
53 of 80 steps (66%) done
Select jobs to execute...
Execute 2 jobs...
[Tue Dec  1 17:37:54 2026] Group job nuts (jobs in lexicogr. order):
    [Tue Dec  1 17:37:54 2026]
    rule sample_nuts:
        input: results/stoch_vol_T5/design_trajectories/trajectories.nc, results/x.json
        output: results/stoch_vol_T5/sample_nuts/batch0.parquet
        log: results/stoch_vol_T5/logs/sample_nuts/batch0.log
        jobid: 27
        wildcards: scenario=stoch_vol_T5, batch=0
        resources: tmpdir=<TBD>, mem_mb=3000, mem=3 GB, mem_mib=2862, runtime=120
Shell command: None
    [Tue Dec  1 17:37:54 2026]
    rule sample_nuts:
        input: results/same_T4/design_trajectories/trajectories.nc, results/y.json
        output: results/same_T4/sample_nuts/batch0.parquet
        log: results/same_T4/logs/sample_nuts/batch0.log
        jobid: 18
        wildcards: scenario=same_T4, batch=0
        resources: tmpdir=<TBD>, mem_mb=3000, mem=3 GB, mem_mib=2862, runtime=120
Shell command: None
[Tue Dec  1 17:37:54 2026]
rule joint_map:
    input: results/stoch_vol_T5/design_trajectories/trajectories.nc
    output: results/stoch_vol_T5/joint_map/joint_map.parquet, results/stoch_vol_T5/joint_map/x.nc
    log: results/stoch_vol_T5/logs/joint_map.log
    jobid: 16
    wildcards: scenario=stoch_vol_T5
    resources: tmpdir=<TBD>, mem_mb=4000, mem=4 GB, mem_mib=3815, disk_mb=1000, runtime=60
Shell command: None
No SLURM account given, trying to guess.
Job 3309d1cd-12e3-5539-b7b4-eaa381815439 has been submitted with SLURM jobid 89 (log: /x/89.log).
Job 16 has been submitted with SLURM jobid 90 (log: /x/.snakemake/slurm_logs/rule_joint_map/90.log).
[Tue Dec  1 17:37:59 2026]
Finished jobid: 4 (Rule: design_trajectories)
"""


def test_logged_units_reads_a_captured_dry_run():
    units = logged_units(DRY_RUN_SAMPLE)
    assert [(u.group, [j.rule for j in u.jobs]) for u in units] == [
        (None, ["build_stan_model"]),
        ("nuts", ["sample_nuts", "sample_nuts"]),
        (None, ["figure_exact_vs_stan"]),
        (None, ["all"]),
    ]
    build, (nuts0, nuts2), figure, all_ = (u.jobs for u in units)
    assert build[0].jobid == "28" and not build[0].local
    assert build[0].output == ("results/shared/stan/native/stoch_vol.json",)
    assert nuts2.jobid == "21" and nuts2.output == ("results/same_T4/sample_nuts/batch2.parquet",)
    assert nuts0.input == (
        "results/ranwalk_T4/design_trajectories/trajectories.nc",
        "results/shared/stan/x.json",
    )
    assert len(figure[0].output) == 2 and all_[0].output == () and all_[0].jobid == "0"
    # two independent Stan jobs, one group job: ceil(2 / PACK); the local rules' jobs run here
    assert connected_components(units[1].jobs) == 2
    expected = expected_submissions(units, {"figure_exact_vs_stan", "all"})
    assert [u.jobs[0].rule for u in expected] == ["build_stan_model", "sample_nuts"]


def test_logged_units_reads_a_captured_run_log():
    units = logged_units(RUN_LOG_SAMPLE)
    assert [(u.group, [(j.rule, j.jobid, j.local) for j in u.jobs]) for u in units] == [
        (None, [("select_k", "29", True)]),
        ("nuts", [("sample_nuts", "27", False), ("sample_nuts", "18", False)]),
        (None, [("joint_map", "16", False)]),
    ]
    assert SUBMITTED.findall(RUN_LOG_SAMPLE) == [
        ("3309d1cd-12e3-5539-b7b4-eaa381815439", "89"),
        ("16", "90"),
    ]


def test_logged_units_rejects_an_indented_job_outside_a_group():
    with pytest.raises(ValueError, match="outside a group job"):
        logged_units("[date]\n    rule sample_nuts:\n        jobid: 3\n")


def test_connected_components_follow_inputs_and_outputs():
    a = LoggedJob("a", local=False, output=("x",))
    b = LoggedJob("b", local=False, input=("x",), output=("y",))
    c = LoggedJob("c", local=False, input=("z",))
    assert connected_components([a, b, c]) == 2 and connected_components([]) == 0


@pytest.mark.cluster
@pytest.mark.slow
def test_every_job_went_through_slurm(cluster_run):
    """One sbatch call per planned submission (every group job, every job of a rule that is not
    local), none for a local job, and no job of a non-local rule run on the submitting host."""
    run = cluster_run
    plan, ran = logged_units(run.plan), logged_units(run.log)
    local = run.local_rules
    expected = expected_submissions(plan, local)
    submitted = SUBMITTED.findall(run.log)
    groups = [len(u.jobs) for u in expected if u.group]
    planned = (
        f"planned: {len(expected) - len(groups)} jobs of non-local rules and {len(groups)} group"
        f" jobs of {groups} jobs; {sum(runs_locally(u, local) for u in plan)} local jobs"
    )
    assert plan and expected and local, run.plan[-3000:]
    assert len(submitted) == len(expected), f"{len(submitted)} sbatch submissions, {planned}"
    assert len({sid for sid, _ in submitted}) == len(submitted), submitted
    assert len({slurm for _, slurm in submitted}) == len(submitted), submitted

    # the run started exactly the planned jobs, each once
    def key(job):
        return job.rule, job.output

    ran_jobs, planned_jobs = (
        sorted(key(j) for u in units for j in u.jobs) for units in (ran, plan)
    )
    assert ran_jobs == planned_jobs, {
        "not planned": sorted(set(ran_jobs) - set(planned_jobs)),
        "not run": sorted(set(planned_jobs) - set(ran_jobs)),
    }
    # on the submitting host: exactly the planned jobs of local rules
    ran_locally = sorted(key(j) for u in ran for j in u.jobs if j.local)
    strays = [k for k in ran_locally if k[0] not in local]
    assert not strays, f"jobs of non-local rules ran on the submitting host: {strays}"
    assert ran_locally == sorted(key(j) for u in plan if runs_locally(u, local) for j in u.jobs)
    # every other job in a submission: its own by Snakemake job id, a group job's by count
    remote = [u for u in ran if not any(j.local for j in u.jobs)]
    assert len(remote) == len(expected), (len(remote), len(expected))
    assert sorted(len(u.jobs) for u in remote if u.group) == sorted(
        len(u.jobs) for u in expected if u.group
    )
    singles = {u.jobs[0].jobid for u in remote if u.group is None}
    submitted_ids = {sid for sid, _ in submitted}
    assert singles <= submitted_ids, sorted(singles - submitted_ids)

    # the sbatch jobs' own output: one log per submission (kept: --slurm-keep-successful-logs),
    # the Stan batches' under group_<id> (`group: nuts`)
    logdir = run.workdir / ".snakemake" / "slurm_logs"
    slurm_logs = sorted(logdir.rglob("*.log"))
    assert len(slurm_logs) == len(expected), (len(slurm_logs), len(expected))
    assert any(p.relative_to(logdir).parts[0].startswith("group_") for p in slurm_logs), slurm_logs
    for job_log in slurm_logs:
        assert "Error" not in job_log.read_text(errors="replace"), job_log


@pytest.mark.cluster
@pytest.mark.slow
def test_tables_identical_to_local_run(cluster_run, smoke_run):
    workdir = cluster_run.workdir
    ours, local = tables(workdir), tables(smoke_run)
    assert len(local) >= 12 and set(ours) == set(local)
    differ = [name for name in local if ours[name] != local[name]]
    assert not differ, f"tables differ between the SLURM and the local run: {differ}"


def kernel_lines(workdir: Path) -> dict[str, str]:
    """Job log -> the kernels it computed with (the line every job logs first, see
    ssmobs/kernels.py), for every job log under results/."""
    found = {}
    for path in sorted((workdir / "results").rglob("*.log")):
        for line in path.read_text(errors="replace").splitlines():
            if " kernels: " in line:
                found[str(path.relative_to(workdir))] = line.split(" kernels: ", 1)[1]
                break
    return found


@pytest.mark.cluster
@pytest.mark.slow
def test_slurm_jobs_compute_with_the_local_kernels(cluster_run, smoke_run):
    """Jobs on SLURM get the settings local jobs get, although submitted from a shell with
    the machine's own kernels and four threads (issue 34)."""
    remote, local = kernel_lines(cluster_run.workdir), kernel_lines(smoke_run)
    assert len(local) >= 10 and set(remote) == set(local), sorted(set(remote) ^ set(local))
    assert len(set(local.values())) == 1, set(local.values())
    assert set(remote.values()) == set(local.values()), (set(remote.values()), local)
