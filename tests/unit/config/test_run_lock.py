"""The lock of a run (ssmobs.config.run_lock): one run per working directory, decided
before it changes a file; Snakemake's own lock, its live holders and a stale one."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from ssmobs.config import run_lock

pytestmark = pytest.mark.unit


# -- the lock --------------------------------------------------------------------------------


def test_only_the_planning_process_may_change_files():
    decision = run_lock.lock_decision(main_process=False, locks=True, holders=[], dry_run=False)
    assert decision == run_lock.LockDecision(False)


@pytest.mark.parametrize("dry_run", [False, True])
def test_without_a_live_lock_files_may_change(dry_run):
    assert run_lock.lock_decision(True, True, [], dry_run) == run_lock.LockDecision(True)


def test_nolock_ignores_the_lock_holders():
    assert run_lock.lock_decision(True, False, [123], False).may_change


def test_a_live_lock_stops_a_run_and_names_the_processes():
    decision = run_lock.lock_decision(True, True, [4242, 4343], dry_run=False)
    assert not decision.may_change and decision.warning is None
    assert decision.error is not None
    assert "Snakemake process(es) [4242, 4343] run here" in decision.error
    assert "stops before it removes or writes anything" in decision.error


def test_a_live_lock_lets_a_dry_run_go_on_changing_nothing():
    decision = run_lock.lock_decision(True, True, [4242], dry_run=True)
    assert not decision.may_change and decision.error is None
    assert decision.warning is not None and "this dry run moves no stale stamp aside" in (
        decision.warning
    )


def test_a_lock_whose_holders_are_unknown_advises_unlock():
    decision = run_lock.lock_decision(True, True, None, dry_run=False)
    assert decision.error is not None and "snakemake --unlock" in decision.error


def test_a_refusal_by_the_run_lock_is_one_line_without_unlock_advice():
    line = "another run of this workflow works in this directory (PID 4242)"
    decision = run_lock.lock_decision(True, True, [], dry_run=False, other_run=line)
    assert not decision.may_change and decision.error is not None
    assert decision.error.startswith(line) and "\n" not in decision.error
    assert "--unlock" not in decision.error and "before it removes or writes anything" in (
        decision.error
    )
    dry = run_lock.lock_decision(True, True, [], dry_run=True, other_run=line)
    assert not dry.may_change and dry.error is None and dry.warning is not None
    assert run_lock.lock_decision(True, False, [], False, other_run=line).may_change  # --nolock


#: a process that holds the run lock of its working directory until it is killed
HOLDER = """
import fcntl, os, sys, time
fd = os.open(".snakemake/ssmobs_run.lock", os.O_RDWR | os.O_CREAT, 0o644)
fcntl.flock(fd, fcntl.LOCK_EX)
os.pwrite(fd, f"{os.getpid()}\\n".encode(), 0)
print("held", flush=True)
time.sleep(300)
"""


def test_the_run_lock_is_one_runs_at_a_time_and_ends_with_its_process(tmp_path, monkeypatch):
    (tmp_path / ".snakemake").mkdir()
    holder = subprocess.Popen(
        [sys.executable, "-c", HOLDER], cwd=tmp_path, stdout=subprocess.PIPE, text=True
    )
    try:
        assert holder.stdout is not None and holder.stdout.readline().strip() == "held"
        monkeypatch.setattr(run_lock, "_HELD", [])
        line = run_lock.take_run_lock(tmp_path)
        assert line == f"another run of this workflow works in this directory (PID {holder.pid})"
        assert run_lock._HELD == []
    finally:
        holder.send_signal(signal.SIGKILL)  # a killed run leaves no lock behind
        holder.wait()
    assert run_lock.take_run_lock(tmp_path) is None
    assert (tmp_path / run_lock.RUN_LOCK).read_text() == f"{os.getpid()}\n"
    assert run_lock.take_run_lock(tmp_path) is None  # held: asked again, still ours
    for fd in run_lock._HELD:
        os.close(fd)


def test_a_directory_that_cannot_be_written_needs_no_run_lock(tmp_path, monkeypatch):
    monkeypatch.setattr(run_lock, "_HELD", [])
    (tmp_path / ".snakemake").write_text("a file where the folder should be")
    assert run_lock.take_run_lock(tmp_path) is None and run_lock._HELD == []


# ------------------------------------------------------------------------ stale locks
def make_lock(workdir: Path) -> None:
    locks = workdir / ".snakemake" / "locks"
    locks.mkdir(parents=True)
    (locks / "0.output.lock").write_text("results/x\n")


def fake_snakemake(cwd: Path) -> subprocess.Popen:
    """A process whose command line mentions snakemake, running in ``cwd``."""
    proc = subprocess.Popen(
        [sys.executable, "-c", "import time; time.sleep(60)", "snakemake"], cwd=cwd
    )
    time.sleep(0.2)
    return proc


def test_no_lock_nothing_to_do(tmp_path):
    assert run_lock.unlock_if_stale(tmp_path, None) is None


@pytest.mark.skipif(not Path("/proc/self/cmdline").exists(), reason="needs /proc (Linux)")
def test_lock_of_a_running_snakemake_is_left_alone(tmp_path):
    make_lock(tmp_path)
    other = tmp_path / "elsewhere"
    other.mkdir()
    proc = fake_snakemake(tmp_path)
    elsewhere = fake_snakemake(other)
    try:
        found = run_lock.snakemake_processes(tmp_path)
        assert proc.pid in found and elsewhere.pid not in found
        note = run_lock.unlock_if_stale(tmp_path, None)
        assert f"PIDs [{proc.pid}]" in note and "left as it is" in note
        assert run_lock.lock_files(tmp_path)
    finally:
        for p in (proc, elsewhere):
            p.kill()
            p.wait()


@pytest.mark.skipif(not Path("/proc/self/cmdline").exists(), reason="needs /proc (Linux)")
def test_lock_holders_are_the_live_snakemake_processes_of_a_locked_directory(tmp_path):
    assert run_lock.lock_holders(tmp_path) == []  # no lock
    make_lock(tmp_path)
    assert run_lock.lock_holders(tmp_path) == []  # a stale lock: no process holds it
    proc = fake_snakemake(tmp_path)
    try:
        assert run_lock.lock_holders(tmp_path) == [proc.pid]
    finally:
        proc.kill()
        proc.wait()
