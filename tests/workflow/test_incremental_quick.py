"""Incremental runs equal fresh runs: the quick cases, on single targets (issue 19).

The mutation suite (``test_incremental.py``, slow) edits a whole run; these cases need only
one rule's outputs: the grid of the choice of K, and the variant x row table, which is made
on request from committed files.  Those on a rare path run in ``make test-slow``.
"""

from __future__ import annotations

import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml
from factories import same_a09
from helpers import REPO, make_workdir, snakemake
from test_incremental import BASE, rules_run

pytestmark = pytest.mark.workflow
#: cases on a rare path (a live lock, the on-request variant table, a config that drops its
#: Stan stage, a read-only results/ or cache, outputs damaged after their job), one to three
#: workflow runs each: `make test-slow` (issue 48)
RARE_PATH = pytest.mark.slow

CONFIG = "config/ksel.yaml"
KSEL = {
    "outputs_dir": "paper_figures/ksel",
    "scenarios": BASE["scenarios"],  # the mutation suite's tiny Same scenario
    "paper_outputs": {"tables_2_3": [], "figure3": [], "figure4": None},
    "k_selection": [
        {
            "name": "same_T4",
            "scenario": "same_T4",
            "K_grid": [4, 8],
            "methods": ["design"],
            "seeds": [1],
            "sets": ["independent"],
        }
    ],
}
#: the choice of K's own outputs (no Stan, no joint MAP of the scenario)
KSEL_TARGET = "results/k_selection/same_T4/v_vectors.csv"


def ksel_run(work: Path, K_grid: list[int]):
    conf = yaml.safe_load(yaml.safe_dump(KSEL))
    conf["k_selection"][0]["K_grid"] = K_grid
    (work / CONFIG).write_text(yaml.safe_dump(conf, sort_keys=False))
    return snakemake(work, KSEL_TARGET, "--cores", "2", "--configfile", CONFIG)


def test_a_changed_k_grid_gives_the_fresh_runs_choice_of_k(tmp_path):
    """Found stale before: the grid files were keyed without K_grid, so a changed grid left
    select_k reading the old K_i. Now a new grid makes new grid files, reusing the points
    both grids hold, and equals a fresh run of the edited config."""
    work = make_workdir(tmp_path / "incremental")
    ksel_run(work, [4, 8])
    (k4,) = work.glob("results/shared/k_selection_points/*/*/K4.json")
    made = k4.stat().st_mtime_ns
    edited = ksel_run(work, [4, 12])
    assert {"k_selection_grid", "select_k"} <= set(rules_run(edited))
    fresh = make_workdir(tmp_path / "fresh")
    ksel_run(fresh, [4, 12])
    assert (work / KSEL_TARGET).read_bytes() == (fresh / KSEL_TARGET).read_bytes()
    points = sorted(p.name for p in k4.parent.glob("K*.json"))
    assert points == ["K12.json", "K4.json", "K8.json"]
    assert k4.stat().st_mtime_ns == made  # K = 4 computed once, found again by the new grid
    assert rules_run(ksel_run(work, [4, 12])) == set()  # and nothing to do again


@RARE_PATH
def test_a_run_refused_by_a_live_lock_changes_nothing(tmp_path):
    """Found before (issue 35): a second run in a directory whose lock a live run held
    removed stale stamps and their files at its parse, before Snakemake refused it."""
    work = make_workdir(tmp_path / "locked")
    ksel_run(work, [4, 8])
    kept = [*work.glob("results/outputs/**/*.key"), work / KSEL_TARGET]
    assert len(kept) > 1
    before = {p: (p.stat().st_mtime_ns, p.read_bytes()) for p in kept}
    locks = work / ".snakemake" / "locks"
    locks.mkdir(parents=True, exist_ok=True)
    (locks / "0.output.lock").write_text("results/of/another/run\n")
    live = subprocess.Popen(  # a live run's process: its command line names snakemake
        [sys.executable, "-c", "import time; time.sleep(300)", "snakemake"], cwd=work
    )
    try:
        conf = yaml.safe_load(yaml.safe_dump(KSEL))
        conf["k_selection"][0]["K_grid"] = [4, 12]  # its stamps are stale for this config
        (work / CONFIG).write_text(yaml.safe_dump(conf, sort_keys=False))
        proc = snakemake(work, KSEL_TARGET, "--cores", "2", "--configfile", CONFIG, check=False)
    finally:
        live.kill()
        live.wait()
    text = proc.stdout + proc.stderr
    assert proc.returncode != 0
    assert "another Snakemake run holds the lock of this directory" in text, text[-2000:]
    assert f"[{live.pid}]" in text and "--unlock" not in text
    assert {p: (p.stat().st_mtime_ns, p.read_bytes()) for p in kept} == before
    # that run has ended: its lock is stale and this run goes on
    assert "select_k" in rules_run(ksel_run(work, [4, 12]))


#: a stand-in for a live run: holds the run lock of its working directory until killed
HOLD_THE_RUN_LOCK = """
import fcntl, os, time
fd = os.open(".snakemake/ssmobs_run.lock", os.O_RDWR | os.O_CREAT, 0o644)
fcntl.flock(fd, fcntl.LOCK_EX)
os.pwrite(fd, f"{os.getpid()}\\n".encode(), 0)
print("held", flush=True)
time.sleep(300)
"""


def _snapshot(work: Path) -> dict[Path, tuple[int, bytes]]:
    """Every file of results/ and outputs_dir with its time and bytes."""
    files = [p for d in ("results", KSEL["outputs_dir"]) for p in (work / d).rglob("*")]
    return {p: (p.stat().st_mtime_ns, p.read_bytes()) for p in files if p.is_file()}


@RARE_PATH
@pytest.mark.parametrize("second", ["the same config", "another config, same outputs_dir"])
def test_a_run_refused_by_the_run_lock_changes_nothing_and_says_so(tmp_path, second):
    """Found before (issue 61): of two configs with one outputs_dir started together, the
    run that lost Snakemake's lock had first removed the other's stamps and tables, then
    ended with Snakemake's LockException; of two runs of one config, the second got
    Snakemake's --unlock advice.  The run lock is taken before any tidying."""
    work = make_workdir(tmp_path / "locked")
    ksel_run(work, [4, 8])
    before = _snapshot(work)
    assert any(p.suffix == ".key" for p in before)
    config = CONFIG
    if second != "the same config":  # its stamps are stale: unlocked, it would remove them
        conf = yaml.safe_load(yaml.safe_dump(KSEL))
        conf["k_selection"][0]["K_grid"] = [4, 12]
        config = "config/ksel_other.yaml"
        (work / config).write_text(yaml.safe_dump(conf, sort_keys=False))
    live = subprocess.Popen(
        [sys.executable, "-c", HOLD_THE_RUN_LOCK], cwd=work, stdout=subprocess.PIPE, text=True
    )
    try:
        assert live.stdout is not None and live.stdout.readline().strip() == "held"
        proc = snakemake(work, KSEL_TARGET, "--cores", "2", "--configfile", config, check=False)
    finally:
        live.kill()
        live.wait()
    text = proc.stdout + proc.stderr
    assert proc.returncode != 0
    line = f"another run of this workflow works in this directory (PID {live.pid})"
    assert f"{line}: this run stops before it removes or writes anything" in text, text[-2000:]
    assert "--unlock" not in text and "LockException" not in text
    assert _snapshot(work) == before


@RARE_PATH
def test_of_two_configs_started_together_one_runs_and_the_other_changes_nothing(tmp_path):
    """Two live runs: the first holds the run lock while it computes a new point; the
    second, whose stamps the first's config makes stale, stops in one line, and the first
    finishes with its tables in place."""
    work = make_workdir(tmp_path / "two")
    ksel_run(work, [4, 8])
    conf = yaml.safe_load(yaml.safe_dump(KSEL))
    conf["k_selection"][0]["K_grid"] = [4, 16]
    (work / "config/ksel_first.yaml").write_text(yaml.safe_dump(conf, sort_keys=False))
    lock = work / ".snakemake" / "ssmobs_run.lock"
    lock.unlink(missing_ok=True)
    first = subprocess.Popen(
        [sys.executable, "-m", "snakemake", KSEL_TARGET, "--cores", "1"]
        + ["--configfile", "config/ksel_first.yaml"],
        cwd=work,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    deadline = time.monotonic() + 120
    while not (lock.is_file() and lock.read_text().strip() == str(first.pid)):
        assert time.monotonic() < deadline and first.poll() is None, "the first run took no lock"
        time.sleep(0.05)
    # the first is held still while the second starts, so it is alive and holds the lock
    # whatever the machine's speed (a warm, idle machine finished it within the second's
    # start-up: a race, not the behaviour under test)
    os.kill(first.pid, signal.SIGSTOP)
    try:
        second = snakemake(work, KSEL_TARGET, "--cores", "1", "--configfile", CONFIG, check=False)
    finally:
        os.kill(first.pid, signal.SIGCONT)
    out, _ = first.communicate(timeout=1800)
    assert first.returncode == 0, out[-3000:]
    text = second.stdout + second.stderr
    assert second.returncode != 0
    assert f"works in this directory (PID {first.pid})" in text, text[-2000:]
    assert "--unlock" not in text and "LockException" not in text
    stamps = list((work / "results" / "outputs" / KSEL["outputs_dir"]).glob("*.key"))
    assert stamps and (work / KSEL_TARGET).is_file()
    assert list(work.glob("results/shared/k_selection_points/*/*/K16.json"))  # the first's


@RARE_PATH
def test_outputs_without_their_checksum_record_are_made_again_not_trusted(tmp_path):
    """Found trusted before (issue 61): a joint MAP summary edited to |K^max| 3, its record
    under results/checksums/ deleted, then ess_bulk_min changed: rc 0 and section4_summary
    with K_max 3.  And results copied without results/checksums/ were trusted alike."""
    from test_incremental import OUT

    work = make_workdir(tmp_path / "w")
    (work / CONFIG).write_text(yaml.safe_dump(BASE, sort_keys=False))
    snakemake(work, "--cores", "2", "--configfile", CONFIG)
    summary = next(work.glob("results/same_T4/joint_map/*/summary.json"))
    made = summary.read_bytes()
    assert b'"K_max": 4' in made
    summary.write_bytes(made.replace(b'"K_max": 4', b'"K_max": 3'))
    (work / "results" / "checksums" / f"{summary.relative_to(work)}.sha256").unlink()
    edited = {**BASE, "convergence": {**BASE["convergence"], "ess_bulk_min": 60}}
    (work / CONFIG).write_text(yaml.safe_dump(edited, sort_keys=False))
    proc = snakemake(work, "--cores", "2", "--configfile", CONFIG)
    assert "has no checksum record" in proc.stdout + proc.stderr
    assert "joint_map" in rules_run(proc) and summary.read_bytes() == made
    section4 = (work / OUT / "section4_summary.csv").read_text().splitlines()
    column = section4[0].split(",").index("K_max")
    assert section4[1].split(",")[column] == "4"
    tables = {p.name: p.read_bytes() for p in (work / OUT).glob("*.csv")}
    # a copy of the results without results/checksums/: everything made again, same bytes
    copy = tmp_path / "copy"
    shutil.copytree(work, copy, ignore=shutil.ignore_patterns(".snakemake"))
    shutil.rmtree(copy / "results" / "checksums")
    again = snakemake(copy, "--cores", "2", "--configfile", CONFIG)
    assert {"joint_map", "gather_nuts", "paper_tables"} <= rules_run(again)
    assert {p.name: p.read_bytes() for p in (copy / OUT).glob("*.csv")} == tables
    assert rules_run(snakemake(copy, "--cores", "2", "--configfile", CONFIG)) == set()


def test_a_model_importing_by_a_name_that_is_no_literal_stops_in_one_line(tmp_path):
    """Issue 61: a model's helper loaded by ``importlib.import_module(name)`` cannot be
    keyed; the run stops before any job, naming the module and line."""
    work = make_workdir(tmp_path / "w")
    (work / "workflow/ssmobs/models/dyn61.py").write_text(
        "import importlib\n\nNAME = 'json'\nhelper = importlib.import_module(NAME)\n"
        "from .same import Same\n\n\nclass Dyn61(Same):\n    slug = 'dyn61'\n"
    )
    scenario = {**BASE["scenarios"][0], "model": "dyn61", "stan": False}
    scenario.pop("paper_ref", None)
    conf = {
        **BASE,
        "scenarios": [scenario],
        "paper_outputs": {"tables_2_3": [], "figure3": [], "figure4": None},
    }
    (work / CONFIG).write_text(yaml.safe_dump(conf, sort_keys=False))
    proc = snakemake(work, "-n", "--cores", "1", "--configfile", CONFIG, check=False)
    text = proc.stdout + proc.stderr
    assert proc.returncode != 0
    assert "module ssmobs.models.dyn61" in text and "line 4)" in text, text[-2000:]
    assert "Traceback" not in text and not (work / "results").exists()


def variant_table_workdir(dest: Path) -> Path:
    """A workflow copy with the committed studies the variant table reads."""
    from ssmobs.reports.stan_variants import read_spec, spec_inputs

    work = make_workdir(dest)
    spec = read_spec(REPO / "config" / "tables" / "stan_variants_by_row.yaml")
    for path in spec_inputs(spec):
        (work / path).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(REPO / path, work / path)
    return work


@RARE_PATH
def test_an_edit_of_the_variant_tables_code_remakes_it(tmp_path):
    """Found stale before: its key was a params value, which Snakemake's rerun by file
    times does not see, so a code edit left the table as it was. Now its stamp holds the
    key of the files it reads and of its code."""
    work = variant_table_workdir(tmp_path / "work")
    first = snakemake(work, "--cores", "1", "stan_variant_table")
    assert rules_run(first) == {"stan_variant_table"}
    assert rules_run(snakemake(work, "--cores", "1", "stan_variant_table")) == set()
    code = work / "workflow" / "ssmobs" / "reports" / "stan_variants.py"
    code.write_text(code.read_text() + "\n# an edit of the table's code\n")
    # another start of Snakemake (here listing the rules) keeps the committed table while stale
    table = sorted(work.glob("paper_figures/stan_variants/variants_by_row.*"))
    assert [t.suffix for t in table] == [".csv", ".md"]
    snakemake(work, "--list-rules")
    assert all(t.is_file() for t in table)
    assert rules_run(snakemake(work, "--cores", "1", "stan_variant_table")) == {
        "stan_variant_table"
    }
    spec = work / "config" / "tables" / "stan_variants_by_row.yaml"
    spec.write_text(spec.read_text() + "\n# an edit of the spec\n")
    assert rules_run(snakemake(work, "--cores", "1", "stan_variant_table")) == {
        "stan_variant_table"
    }


@RARE_PATH
def test_outputs_of_an_earlier_config_are_moved_out_of_outputs_dir(tmp_path):
    """Issue 35: after ``stan: false`` the earlier run's exact-vs-Stan tables and figures and
    their stamp stayed, so outputs_dir showed a mix of two configs."""
    from test_incremental import OUT

    work = make_workdir(tmp_path / "w")
    first = {**BASE, "k_selection": [], "observability_studies": []}
    (work / CONFIG).write_text(yaml.safe_dump(first, sort_keys=False))
    snakemake(work, "--cores", "2", "--configfile", CONFIG)
    stan_only = sorted(p.name for p in (work / OUT).glob("*exact_vs_stan*"))
    assert stan_only, sorted(p.name for p in (work / OUT).iterdir())
    stamps = {p.name for p in (work / "results" / "outputs" / OUT).glob("*.key")}
    second = {
        **first,
        "scenarios": [{**sc, "stan": False} for sc in first["scenarios"]],
        "paper_outputs": {"tables_2_3": [], "figure3": [], "figure4": None},
    }
    (work / CONFIG).write_text(yaml.safe_dump(second, sort_keys=False))
    proc = snakemake(work, "--cores", "2", "--configfile", CONFIG)
    assert f"file(s) that this config does not make out of {OUT}" in proc.stderr
    assert not list((work / OUT).glob("*exact_vs_stan*"))
    (aside,) = (work / "results" / "outputs" / OUT / "set_aside").iterdir()
    assert stan_only == sorted(p.name for p in aside.glob("*exact_vs_stan*"))
    left = {p.name for p in (work / "results" / "outputs" / OUT).glob("*.key")}
    assert left < stamps and not any("exact_vs_stan" in s for s in left), (stamps, left)
    # what stays is exactly what this config makes: a third run has nothing to do or move
    again = snakemake(work, "--cores", "2", "--configfile", CONFIG)
    assert (
        "does not make" not in again.stderr and "Nothing to be done" in again.stdout + again.stderr
    )


def test_a_cold_cache_without_a_compiler_stops_before_any_job_with_one_line(tmp_path):
    """Issue 35: a cold cache without g++ gave a 45-line traceback from a build job."""
    import os

    work = make_workdir(tmp_path / "w")
    (work / CONFIG).write_text(yaml.safe_dump(BASE, sort_keys=False))
    env = {**os.environ, "CXX": "no-such-compiler", "SSMOBS_CACHE": str(tmp_path / "cold")}
    proc = snakemake(work, "--cores", "1", "--configfile", CONFIG, check=False, env=env)
    assert proc.returncode != 0
    text = proc.stdout + proc.stderr
    assert "must build 1 program(s) (same) but finds no C++ compiler 'no-such-compiler'" in text
    assert "Traceback" not in text and not (work / "results").exists()
    dry = snakemake(work, "-n", "--cores", "1", "--configfile", CONFIG, env=env)
    assert "finds no C++ compiler" in dry.stdout + dry.stderr


#: Figure 2 of the tiny config: one design set and one figure job (seconds)
FIGURE2 = f"{BASE['outputs_dir']}/fig2_design_points.png"


def snakemake_as(prefix: list[str], work: Path, *args: str) -> subprocess.CompletedProcess:
    """Snakemake in ``work`` after ``prefix`` (e.g. a command that drops a privilege)."""
    return subprocess.run(
        [*prefix, sys.executable, "-m", "snakemake", *args],
        cwd=work,
        capture_output=True,
        text=True,
        timeout=600,
    )


def jobs_started(proc: subprocess.CompletedProcess) -> list[str]:
    """The rules of the jobs Snakemake started (its 'rule x:' / 'localrule x:' lines)."""
    import re

    return re.findall(r"^(?:local)?rule (\w+):$", proc.stdout + proc.stderr, re.M)


@RARE_PATH
def test_a_read_only_cache_stops_before_any_job_and_a_run_with_nothing_to_do_reads_it(
    tmp_path,
):
    """Issue 35: jobs started in a read-only results/ and failed with tracebacks (the clear
    line only in their logs).  Now the run stops before its first job with one line naming
    results/ and what to do, while a run with nothing to do, and a dry run, need no writing.
    results/ is made read-only with chmod; root writes through permission bits, so as root
    Snakemake runs without that override (setpriv drops CAP_DAC_OVERRIDE), as another user
    would (tests/unit/config/test_preflight.py also checks a read-only file system)."""
    import os

    prefix = []
    if os.geteuid() == 0:
        if shutil.which("setpriv") is None:
            pytest.skip("running as root, and setpriv (to drop root's override) is missing")
        prefix = ["setpriv", "--bounding-set", "-dac_override,-dac_read_search"]
    work = make_workdir(tmp_path / "w")
    (work / CONFIG).write_text(yaml.safe_dump(BASE, sort_keys=False))
    snakemake(work, FIGURE2, "--cores", "2", "--configfile", CONFIG)
    folders = [p for p in (work / "results").rglob("*") if p.is_dir()] + [work / "results"]
    for folder in folders:
        folder.chmod(0o555)
    # Figure 2 edited: its stamp is stale, which the parse moves aside (dry) or removes
    edited = "config/edited.yaml"
    (work / edited).write_text(yaml.safe_dump({**BASE, "figure2": {"a": 0.5}}, sort_keys=False))
    try:
        same = snakemake_as(prefix, work, FIGURE2, "--cores", "2", "--configfile", CONFIG)
        dry = snakemake_as(prefix, work, "-n", "--cores", "2", "--configfile", CONFIG)
        full = snakemake_as(prefix, work, "--cores", "2", "--configfile", CONFIG)
        stale_dry = snakemake_as(
            prefix, work, "-n", FIGURE2, "--cores", "2", "--configfile", edited
        )
        stale = snakemake_as(prefix, work, FIGURE2, "--cores", "2", "--configfile", edited)
    finally:
        for folder in folders:
            folder.chmod(0o755)
    assert same.returncode == 0 and "Nothing to be done" in same.stdout + same.stderr
    assert dry.returncode == 0, dry.stderr[-2000:]
    for proc in (full, stale):
        text = proc.stdout + proc.stderr
        assert proc.returncode != 0
        assert "this run cannot write where its jobs write: results (not writable by user" in text
        assert "make results/ (this working directory's cache) writable" in text
        assert jobs_started(proc) == [] and "Traceback" not in text, text[-3000:]
    assert stale_dry.returncode == 0, stale_dry.stderr[-2000:]
    assert "this dry run leaves the stale results/outputs/" in stale_dry.stdout + stale_dry.stderr
    # the refused run removed nothing, not even Figure 2 in the writable outputs_dir
    assert (work / FIGURE2).is_file()


@RARE_PATH
def test_a_read_only_cold_cache_stops_nuts_jobs_whose_program_results_knows(tmp_path):
    """Found before (issue 46): with the program's marker and Stan check already in
    results/, a read-only SSMOBS_CACHE without the program let two sample_nuts jobs start
    (rc 2, 8 tracebacks).  Now one line names the cache and the remedy, before any job."""
    import os

    prefix = []
    if os.geteuid() == 0:
        if shutil.which("setpriv") is None:
            pytest.skip("running as root, and setpriv (to drop root's override) is missing")
        prefix = ["setpriv", "--bounding-set", "-dac_override,-dac_read_search"]
    work = make_workdir(tmp_path / "w")
    (work / CONFIG).write_text(yaml.safe_dump(BASE, sort_keys=False))
    until = ["--until", "check_model_stan"]
    snakemake(work, *until, "--cores", "2", "--configfile", CONFIG)
    assert list(work.glob("results/shared/stan/*/same/*.json"))  # the program's marker
    cold = tmp_path / "cold"
    cold.mkdir()
    cold.chmod(0o555)
    env = {**os.environ, "SSMOBS_CACHE": str(cold)}
    try:
        proc = subprocess.run(
            [*prefix, sys.executable, "-m", "snakemake", "--cores", "2", "--configfile", CONFIG],
            cwd=work,
            capture_output=True,
            text=True,
            timeout=600,
            env=env,
        )
    finally:
        cold.chmod(0o755)
    text = proc.stdout + proc.stderr
    assert proc.returncode != 0
    assert f"this run cannot write where its jobs write: {cold} (not writable by user" in text
    assert "point SSMOBS_CACHE at a writable folder" in text
    assert jobs_started(proc) == [] and "Traceback" not in text, text[-3000:]


def test_an_outputs_dir_below_a_file_stops_before_any_job_with_one_line(tmp_path):
    """No permission bit involved (so it holds for root too): paper_figures is a file."""
    work = make_workdir(tmp_path / "w")
    (work / CONFIG).write_text(yaml.safe_dump(BASE, sort_keys=False))
    (work / "paper_figures").write_text("a file, not a folder\n")
    proc = snakemake(work, FIGURE2, "--cores", "2", "--configfile", CONFIG, check=False)
    text = proc.stdout + proc.stderr
    assert proc.returncode != 0
    assert (
        "this run cannot write where its jobs write: paper_figures (a file, not a folder); "
        f"make outputs_dir = {BASE['outputs_dir']} writable, or set outputs_dir to a "
        "writable folder; no job was started"
    ) in text
    assert jobs_started(proc) == [] and "Traceback" not in text
    assert not (work / "results").exists()  # nothing was made, not even the design set


def test_fifty_large_scenarios_give_a_short_message_from_snakemake_too(tmp_path):
    """Issue 35: 50 large scenarios gave a message of about 100-250 lines at the parse."""
    work = make_workdir(tmp_path / "w")
    base = same_a09(name=None, T=400, K=200_000)
    conf = {
        "outputs_dir": "paper_figures/big",
        "scenarios": [{"name": f"big_{i:02d}", **base} for i in range(50)],
        "paper_outputs": {"tables_2_3": [], "figure3": [], "figure4": None},
    }
    (work / CONFIG).write_text(yaml.safe_dump(conf, sort_keys=False))
    proc = snakemake(work, "-n", "--configfile", CONFIG, check=False, timeout=300)
    text = proc.stdout + proc.stderr
    assert proc.returncode != 0
    assert len(text.splitlines()) <= 20, text
    assert (
        "(102 problems of 4 kinds; every one: .venv/bin/python -m ssmobs.config.preflight" in text
    )
    assert "50 scenarios alike, the first: scenario 'big_00': a design_disturbances job" in text
    # the fourth kind: the joint MAP's time budget (limits.joint_map_cpu_hours, issue 61)
    assert "more than limits.joint_map_cpu_hours" in text


def test_the_model_check_runs_after_the_build_of_its_program(tmp_path):
    """Issue 48: with the native backend every check_model_stan job takes its program's
    build_stan_model marker as input, so the one compile happens in the build job and no
    check compiles or waits on the build lock (here: a dry run of every job of the smoke
    profile)."""
    work = make_workdir(tmp_path)
    conf = yaml.safe_load((work / "config" / "smoke.yaml").read_text())
    conf["stan"] = {**conf.get("stan", {}), "backend": "native"}
    (work / "config" / "native.yaml").write_text(yaml.safe_dump(conf))
    proc = snakemake(work, "-n", "--forceall", "--cores", "2", "--configfile", "config/native.yaml")
    jobs = []  # (rule, {"input": [...], "output": [...]}) of every planned job
    for block in re.split(r"^(?:local)?rule ", proc.stdout, flags=re.M)[1:]:
        fields = re.findall(r"^\s+(input|output): (.*)$", block, flags=re.M)
        jobs.append((block.split(":", 1)[0], {k: v.split(", ") for k, v in fields}))
    builds = {p for rule, f in jobs if rule == "build_stan_model" for p in f["output"]}
    checks = [f["input"] for rule, f in jobs if rule == "check_model_stan"]
    assert builds and checks
    for inputs in checks:
        assert builds & set(inputs), inputs


def _damage_keeping_time(path: Path, content: bytes) -> None:
    st = path.stat()
    path.write_bytes(content)
    os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns))


@RARE_PATH
def test_outputs_damaged_after_their_job_are_made_again_not_read(tmp_path):
    """Found reused before (issue 46): an output edited or truncated with its time kept
    gave "Nothing to be done" and flowed into the tables after a later edit.  Every job
    records its outputs' checksums; a mismatch is said once and the file made again: a
    requested table at once, an intermediate grid file when a job reads it."""
    work = make_workdir(tmp_path / "damaged")
    ksel_run(work, [4, 8])
    table = work / KSEL_TARGET
    (grid,) = work.glob("results/k_selection/same_T4/*/design_independent_seed1.json")
    intact = {p: p.read_bytes() for p in (table, grid)}
    _damage_keeping_time(table, b"")  # truncated to 0 bytes
    _damage_keeping_time(grid, intact[grid].replace(b"1", b"2", 1))  # edited in place
    proc = ksel_run(work, [4, 8])
    said = [line for line in proc.stderr.splitlines() if "made again, not reused" in line]
    assert len(said) == 2, said
    assert any(f"{table.relative_to(work)} is empty" in line for line in said)
    assert {"k_selection_grid", "select_k"} <= set(rules_run(proc))
    assert {p: p.read_bytes() for p in intact} == intact
    assert rules_run(ksel_run(work, [4, 8])) == set()  # and nothing to do again
