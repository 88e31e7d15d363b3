"""Interrupt and resume, determinism and damaged caches on the smoke config (issue 6)."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from helpers import SMOKE, kill_when, make_workdir, snakemake

pytestmark = [pytest.mark.workflow, pytest.mark.slow]

TABLE_GLOBS = ["paper_figures/*.csv", "paper_figures/*.md", "paper_figures/*.tex",
               "results/*/joint_map/joint_map.parquet", "results/*/gather_nuts/*.parquet",
               "results/k_selection/*/*.csv"]


def final_tables(workdir: Path) -> dict[str, bytes]:
    out = {}
    for pattern in TABLE_GLOBS:
        for f in sorted(workdir.glob(pattern)):
            out[str(f.relative_to(workdir))] = f.read_bytes()
    return out


def records(workdir: Path) -> dict[str, tuple[int, bytes]]:
    return {str(f.relative_to(workdir)): (f.stat().st_mtime_ns, f.read_bytes())
            for f in sorted(workdir.glob("results/*/sample_nuts/records/k*.json"))}


def resume(workdir: Path) -> None:
    snakemake(workdir, "--unlock", *SMOKE)
    snakemake(workdir, "--cores", "2", "--rerun-incomplete", *SMOKE)


def assert_same_tables(a: Path, b: Path) -> None:
    ta, tb = final_tables(a), final_tables(b)
    assert ta, "no tables found"
    assert sorted(ta) == sorted(tb)
    different = [name for name in ta if ta[name] != tb[name]]
    assert not different, f"tables differ: {different}"


def test_interrupted_stan_stage_resumes_without_recomputing(smoke_run, tmp_path):
    workdir = make_workdir(tmp_path)
    kill_when(workdir, ["--cores", "2", *SMOKE],
              lambda w: len(list(w.glob("results/*/sample_nuts/records/k*.json"))) >= 3)
    before = records(workdir)
    assert before, "no record was finished before the kill"
    resume(workdir)
    after = records(workdir)
    for name, (mtime, content) in before.items():
        assert after[name] == (mtime, content), f"{name} was recomputed"
    assert_same_tables(smoke_run, workdir)


def test_interrupted_design_stage_resumes(smoke_run, tmp_path):
    workdir = make_workdir(tmp_path)
    kill_when(workdir, ["--cores", "2", *SMOKE],
              lambda w: len(list(w.glob("results/shared/design_disturbances/*.nc"))) >= 1)
    resume(workdir)
    assert_same_tables(smoke_run, workdir)


def test_cores_1_gives_byte_identical_tables(smoke_run, tmp_path):
    workdir = make_workdir(tmp_path)
    snakemake(workdir, "--cores", "1", *SMOKE)
    assert_same_tables(smoke_run, workdir)


def copy_run(src: Path, dest: Path) -> Path:
    shutil.copytree(src, dest, symlinks=True, ignore=shutil.ignore_patterns("locks"))
    return dest


def test_corrupted_record_is_recomputed(smoke_run, tmp_path):
    workdir = copy_run(smoke_run, tmp_path / "run")
    recs = sorted(workdir.glob("results/same_T4/sample_nuts/records/k*.json"))
    victim, other = recs[0], recs[1]
    other_state = (other.stat().st_mtime_ns, other.read_bytes())
    victim.write_text(victim.read_text()[:40])
    (workdir / "results/same_T4/sample_nuts/batch0.parquet").unlink()
    snakemake(workdir, "--cores", "2", *SMOKE)
    assert (other.stat().st_mtime_ns, other.read_bytes()) == other_state
    assert victim.read_text().rstrip().endswith("}")
    assert_same_tables(smoke_run, workdir)


def test_damaged_trajectories_are_reported_by_name(smoke_run, tmp_path):
    workdir = copy_run(smoke_run, tmp_path / "run")
    traj = workdir / "results/same_T4/design_trajectories/trajectories.nc"
    traj.write_bytes(traj.read_bytes()[:500])
    proc = snakemake(workdir, "--cores", "2", *SMOKE, check=False)
    assert proc.returncode != 0
    assert "results/same_T4/design_trajectories/trajectories.nc" in proc.stdout + proc.stderr
    # the remedy the message gives: delete it; the rerun recomputes it and everything after
    traj.unlink()
    snakemake(workdir, "--cores", "2", *SMOKE)
    assert_same_tables(smoke_run, workdir)
