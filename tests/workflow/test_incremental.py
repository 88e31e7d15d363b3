"""Incremental runs equal fresh runs: the mutation suite of issue 19.

From one finished run of a tiny config, each case applies one edit (a config value, a
model's module, a Stan program, a stage's code), reruns the same command and checks that

(a) the rerun exits 0,
(b) every table and summary is byte-identical to a fresh run of the edited config in an
    empty ``results/`` (same keyed paths, same bytes), and
(c) the rules that ran are the ones the edit touches (e.g. a convergence threshold reruns
    no NUTS sampling, a joint-MAP setting no Stan job).

Reverting an edit finds the earlier outputs again, also without ``.snakemake/``.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml
from factories import same_a09
from helpers import make_workdir, snakemake

pytestmark = [pytest.mark.workflow, pytest.mark.slow]

CONFIG = "config/mutation.yaml"
OUT = "paper_figures/mutation"
ARGS = ["--cores", "2", "--rerun-incomplete", "--configfile", CONFIG]

BASE = {
    "outputs_dir": OUT,
    "scenarios": [same_a09(name="same_T4", prior="restricted", paper_ref="same_a09_T4")],
    "paper_outputs": {"tables_2_3": ["same_T4"], "figure3": ["same_T4"], "figure4": None},
    "k_selection": [],
    "observability_studies": [],
    "stan": {"chains": 2, "iter_warmup": 150, "iter_sampling": 150, "batch_size": 2},
    "convergence": {"ess_bulk_min": 50, "ess_tail_min": 50},
}

#: the files compared between an incremental and a fresh run (tables, summaries, keyed data)
COMPARED = [
    f"{OUT}/*.csv",
    f"{OUT}/*.md",
    f"{OUT}/*.tex",
    "results/*/design_trajectories/*/trajectories.nc",
    "results/*/joint_map/*/*.parquet",
    "results/*/joint_map/*/summary.json",
    "results/*/sample_nuts/*/batch*.parquet",
    "results/*/gather_nuts/*/*.parquet",
    "results/*/gather_nuts/*/summary.json",
    "results/*/exact_marginal/*/*.parquet",
    "results/*/exact_marginal/*/summary.json",
]

EVERY_STAGE = {
    "design_trajectories",
    "joint_map",
    "sample_nuts",
    "gather_nuts",
    "exact_marginal",
    "paper_tables",
}


def _set(path: str, value):
    def edit(conf: dict) -> None:
        node = conf
        *parents, last = path.split(".")
        for p in parents:
            node = node[int(p)] if p.isdigit() else node.setdefault(p, {})
        node[last] = value

    return edit


def _append(relpath: str, text: str):
    def edit(work: Path) -> None:
        f = work / relpath
        f.write_text(f.read_text() + text)

    return edit


#: name -> (config edit or None, file edit or None, rules that must run, rules that must not)
CASES = {
    "omega": (
        _set("scenarios.0.omega.a", 0.8),
        None,
        EVERY_STAGE | {"check_model", "check_model_stan"},
        {"design_disturbances", "build_stan_model"},
    ),
    "x0": (_set("scenarios.0.x0", 7), None, EVERY_STAGE, {"design_disturbances"}),
    "T": (_set("scenarios.0.T", 5), None, EVERY_STAGE | {"design_disturbances"}, set()),
    "K": (
        _set("scenarios.0.K", 3),
        None,
        EVERY_STAGE | {"design_disturbances"},
        {"check_model", "build_stan_model"},
    ),
    "seed": (
        _set("scenarios.0.seed", 2),
        None,
        EVERY_STAGE | {"design_disturbances"},
        {"check_model", "build_stan_model"},
    ),
    "prior": (
        _set("scenarios.0.prior", "unrestricted"),
        None,
        {"joint_map", "sample_nuts", "gather_nuts", "exact_marginal", "paper_tables"},
        {"design_trajectories", "design_disturbances", "check_model", "check_model_stan"},
    ),
    "convergence threshold": (
        _set("convergence.rhat_max", 1.05),
        None,
        {"sample_nuts", "gather_nuts", "paper_tables"},
        {"design_trajectories", "joint_map", "exact_marginal", "check_model", "check_model_stan"},
    ),
    "stan setting": (
        _set("stan.iter_sampling", 160),
        None,
        {"sample_nuts", "gather_nuts", "paper_tables"},
        {"design_trajectories", "joint_map", "exact_marginal", "check_model", "check_model_stan"},
    ),
    "Stan subset": (  # issue 20: k = 0, 2 of the K = 4 are the full set's runs, reused
        _set("scenarios.0.stan_every", 2),
        None,
        {"sample_nuts", "gather_nuts", "paper_tables"},
        {"design_trajectories", "joint_map", "exact_marginal", "check_model", "check_model_stan"},
    ),
    "joint-MAP setting": (
        _set("joint_map.grad_tol", 2e-5),
        None,
        {"joint_map", "paper_tables"},
        {"design_trajectories", "sample_nuts", "gather_nuts", "exact_marginal"},
    ),
    "exact stage code": (
        None,
        _append("workflow/ssmobs/exact/marginal.py", "\n# an edit of the exact stage\n"),
        {"exact_marginal", "paper_tables"},
        {"design_trajectories", "joint_map", "sample_nuts"},
    ),
    "model module": (  # Figure 2 draws model Same's trajectories: it is remade too
        None,
        _append("workflow/ssmobs/models/same.py", "\nEDITED = 1  # an edit of the model\n"),
        EVERY_STAGE | {"check_model", "check_model_stan", "figure_design_points"},
        {"design_disturbances", "build_stan_model"},
    ),
    "model comment": (  # issue 35: what the model computes is keyed, not its comments
        None,
        _append("workflow/ssmobs/models/same.py", "\n# a comment on the model\n"),
        set(),
        EVERY_STAGE | {"check_model", "check_model_stan", "figure_design_points"},
    ),
    "Stan program": (
        None,
        _append("stan/same.stan", "\n// an edit of the Stan program\n"),
        {"build_stan_model", "check_model_stan", "sample_nuts", "gather_nuts", "paper_tables"},
        {"check_model", "design_trajectories", "joint_map", "exact_marginal"},
    ),
}


#: a model of ours that imports a helper (skipped by model discovery) and subclasses Same,
#: with a Stan program made of ``#include`` files
OWN_MODEL = {
    # a module of the project tree outside the package (jobs import it from workflow/)
    "workflow/mixhelper.py": "BASE_SCALE = 1.0\n",
    "workflow/ssmobs/models/_mix.py": "from mixhelper import BASE_SCALE\n\nSCALE = BASE_SCALE\n",
    "workflow/ssmobs/models/same_mix.py": (
        '"""Same under another slug, from a helper and its base model."""\n\n'
        "from ._mix import SCALE\nfrom .same import Same\n\n\n"
        "class SameMix(Same):\n    slug = 'same_mix'\n    scale = SCALE\n"
    ),
    "stan/same_mix.stan": "// Same, from its parts\n#include <_same_mix_body.stan>\n",
}
#: the cases on that model: name -> (file edit, rules that must run, rules that must not)
OWN_MODEL_CASES = {
    "helper module": (
        _append("workflow/ssmobs/models/_mix.py", "\nEDITED = 1\n"),
        EVERY_STAGE | {"check_model", "check_model_stan"},
        {"design_disturbances", "build_stan_model"},
    ),
    "helper in the project tree": (  # issue 46: it was not keyed ("Nothing to be done")
        _append("workflow/mixhelper.py", "\nEDITED = 1\n"),
        EVERY_STAGE | {"check_model", "check_model_stan"},
        {"design_disturbances", "build_stan_model"},
    ),
    "base model": (
        _append("workflow/ssmobs/models/same.py", "\nEDITED = 1\n"),
        EVERY_STAGE | {"check_model", "check_model_stan"},
        {"design_disturbances", "build_stan_model"},
    ),
    "Stan include": (
        _append("stan/_same_mix_body.stan", "\n// an edit of an included file\n"),
        {"build_stan_model", "check_model_stan", "sample_nuts", "gather_nuts", "paper_tables"},
        {"check_model", "design_trajectories", "joint_map", "exact_marginal"},
    ),
}


def add_own_model(work: Path) -> None:
    """Write :data:`OWN_MODEL` (the Stan body: the text of same.stan) and use it."""
    for name, text in OWN_MODEL.items():
        (work / name).write_text(text)
    (work / "stan" / "_same_mix_body.stan").write_text((work / "stan" / "same.stan").read_text())
    write_config(work, _set("scenarios.0.model", "same_mix"))


def write_config(work: Path, edit=None) -> None:
    conf = yaml.safe_load(yaml.safe_dump(BASE))
    if edit is not None:
        edit(conf)
    (work / CONFIG).write_text(yaml.safe_dump(conf, sort_keys=False))


def rules_run(proc) -> set[str]:
    """Names of the rules whose jobs ran, from Snakemake's log."""
    text = proc.stdout + proc.stderr
    return set(re.findall(r"^(?:local)?rule (\w+):$", text, flags=re.M)) - {"all"}


def compared_files(work: Path) -> dict[str, bytes]:
    out = {}
    for pattern in COMPARED:
        for f in sorted(work.glob(pattern)):
            out[str(f.relative_to(work))] = f.read_bytes()
    return out


@pytest.fixture(scope="module")
def base(tmp_path_factory) -> Path:
    """One finished run of the tiny config (the baseline every case starts from)."""
    work = make_workdir(tmp_path_factory.mktemp("mutation_base"))
    write_config(work)
    snakemake(work, *ARGS)
    return work


def run_both(*workdirs: Path) -> list[subprocess.CompletedProcess]:
    """The same command in each workdir at once (their serial chains share the 2 cores)."""
    procs = [
        subprocess.Popen(
            [sys.executable, "-m", "snakemake", *ARGS],
            cwd=w,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for w in workdirs
    ]
    done = []
    for w, proc in zip(workdirs, procs):
        out, err = proc.communicate(timeout=3600)
        assert proc.returncode == 0, f"{w}: {out[-2000:]}\n{err[-4000:]}"
        done.append(subprocess.CompletedProcess(proc.args, proc.returncode, out, err))
    return done


def _copy(src: Path, dest: Path) -> Path:
    shutil.copytree(src, dest, symlinks=True, ignore=shutil.ignore_patterns("locks"))
    return dest


def assert_fresh_equal(incremental: Path, fresh: Path) -> None:
    """Every compared file of the fresh run exists in the incremental run, byte for byte."""
    want = compared_files(fresh)
    assert want, "the fresh run wrote nothing to compare"
    have = compared_files(incremental)
    missing = sorted(set(want) - set(have))
    assert not missing, f"not in the incremental run (other keys?): {missing[:5]}"
    differ = sorted(name for name in want if want[name] != have[name])
    assert not differ, f"differ from a fresh run: {differ}"


@pytest.mark.parametrize("case", list(CASES), ids=list(CASES))
def test_an_edit_reruns_what_it_touches_and_equals_a_fresh_run(base, tmp_path, case):
    config_edit, file_edit, must_run, must_not_run = CASES[case]
    work = _copy(base, tmp_path / "incremental")
    fresh = make_workdir(tmp_path / "fresh")
    for w in (work, fresh):
        write_config(w, config_edit)
        if file_edit is not None:
            file_edit(w)
    proc, _ = run_both(work, fresh)
    ran = rules_run(proc)
    assert must_run <= ran, f"did not rerun {sorted(must_run - ran)} (ran {sorted(ran)})"
    assert not (must_not_run & ran), f"reran {sorted(must_not_run & ran)}"
    if case in ("convergence threshold", "Stan subset"):  # batches rebuilt from records
        new = set(work.glob("results/same_T4/sample_nuts/*/*.log")) - {
            work / p.relative_to(base) for p in base.glob("results/same_T4/sample_nuts/*/*.log")
        }
        assert new and all("0 trajectories to sample" in p.read_text() for p in new)
    again = snakemake(work, *ARGS, "-n")
    assert "Nothing to be done" in again.stdout + again.stderr
    assert_fresh_equal(work, fresh)


#: one output of every stage, each damaged another way with its time kept (issue 46)
DAMAGED_OUTPUTS = {
    "results/shared/design_disturbances/*/q*.nc": "truncate",
    "results/same_T4/check_model/*.json": "edit",
    "results/same_T4/joint_map/*/summary.json": "edit",
    "results/same_T4/joint_map/*/theta_hat.nc": "empty",
    "results/same_T4/sample_nuts/*/batch0.parquet": "flip",
    "results/same_T4/gather_nuts/*/summary.json": "edit",
    "results/same_T4/exact_marginal/*/marginal_map.parquet": "truncate",
    f"{OUT}/table2_joint_vs_marginal.csv": "empty",
    f"{OUT}/section4_summary.md": "edit",
}


def _damage(path: Path, how: str) -> None:
    st = path.stat()
    data = path.read_bytes()
    if how == "truncate":
        data = data[: len(data) // 2]
    elif how == "empty":
        data = b""
    elif how == "flip":  # one byte in the middle, the size kept
        data = (
            data[: len(data) // 2] + bytes([data[len(data) // 2] ^ 1]) + data[len(data) // 2 + 1 :]
        )
    else:  # an edit into other valid content, e.g. a_mse 0.5, K_max 3
        data = re.sub(rb"\d", b"3", data, count=3)
    path.write_bytes(data)
    os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns))


def test_a_damaged_output_of_every_stage_is_made_again_not_read(base, tmp_path):
    """Found reused before (issue 46): joint_map's summary.json edited with its time kept
    flowed into the summary table after a threshold edit; a table truncated to 0 bytes
    stayed.  One output of every stage damaged: the same command says each once, makes each
    again (the same bytes as the run that made it) and equals a fresh run after a threshold
    edit that rereads them; then there is nothing to do."""
    work = _copy(base, tmp_path / "damaged")
    damaged = {}
    for pattern, how in DAMAGED_OUTPUTS.items():
        path = first(work, pattern)
        damaged[path] = path.read_bytes()
        _damage(path, how)
    proc = snakemake(work, *ARGS)
    text = proc.stdout + proc.stderr
    for path, content in damaged.items():
        name = str(path.relative_to(work))
        said = [line for line in text.splitlines() if name in line and "made again" in line]
        assert len(said) == 1, (name, said)
        assert path.read_bytes() == content, f"{name} not made again as it was"
    again = snakemake(work, *ARGS, "-n")
    assert "Nothing to be done" in again.stdout + again.stderr
    fresh = make_workdir(tmp_path / "fresh")
    for w in (work, fresh):
        write_config(w, _set("convergence.rhat_max", 1.05))
    run_both(work, fresh)
    assert_fresh_equal(work, fresh)


def first(work: Path, pattern: str) -> Path:
    found = sorted(work.glob(pattern))
    assert found, pattern
    return found[0]


@pytest.fixture(scope="module")
def own_base(tmp_path_factory) -> Path:
    """One finished run of the tiny config on :data:`OWN_MODEL`."""
    work = make_workdir(tmp_path_factory.mktemp("mutation_own_base"))
    add_own_model(work)
    snakemake(work, *ARGS)
    return work


@pytest.mark.parametrize("case", list(OWN_MODEL_CASES), ids=list(OWN_MODEL_CASES))
def test_an_edit_of_what_a_model_imports_reruns_it(own_base, tmp_path, case):
    """Found stale before (issue 35): an edit of a helper the model imports, of the model it
    subclasses or of a file its Stan program includes gave "Nothing to be done"."""
    file_edit, must_run, must_not_run = OWN_MODEL_CASES[case]
    work = _copy(own_base, tmp_path / "incremental")
    fresh = make_workdir(tmp_path / "fresh")
    add_own_model(fresh)
    for w in (work, fresh):
        file_edit(w)
    proc, _ = run_both(work, fresh)
    ran = rules_run(proc)
    assert must_run <= ran, f"did not rerun {sorted(must_run - ran)} (ran {sorted(ran)})"
    assert not (must_not_run & ran), f"reran {sorted(must_not_run & ran)}"
    again = snakemake(work, *ARGS, "-n")
    assert "Nothing to be done" in again.stdout + again.stderr
    assert_fresh_equal(work, fresh)


@pytest.mark.parametrize("metadata", [True, False], ids=["with metadata", "without .snakemake"])
def test_reverting_an_edit_finds_the_earlier_outputs(base, tmp_path, metadata):
    """Edit, run, edit back, run: the tables are the baseline's again, recomputing only the
    tables (stamps, not file times or Snakemake's metadata, tell them stale)."""
    work = _copy(base, tmp_path / "revert")
    write_config(work, _set("convergence.rhat_max", 1.05))  # new keys from the batches on
    snakemake(work, *ARGS)
    write_config(work)
    if not metadata:
        shutil.rmtree(work / ".snakemake")
    proc = snakemake(work, *ARGS)
    ran = rules_run(proc)
    assert "paper_tables" in ran
    assert not ({"design_trajectories", "joint_map", "sample_nuts"} & ran), ran
    assert_fresh_equal(work, base)
    tables = {f.name: f.read_bytes() for f in (base / OUT).glob("*.csv")}
    assert tables and all((work / OUT / n).read_bytes() == b for n, b in tables.items())


def test_profiles_share_no_output(base, tmp_path):
    """Two configs with the same scenario name but another K share no trajectories, and
    each keeps its own tables (issue 19, items 7 and 9)."""
    work = _copy(base, tmp_path / "profiles")
    other = yaml.safe_load(yaml.safe_dump(BASE))
    other["outputs_dir"] = "paper_figures/other"
    other["scenarios"][0]["K"] = 6
    (work / "config" / "other.yaml").write_text(yaml.safe_dump(other))
    proc = snakemake(work, "-n", "--cores", "2", "--configfile", "config/other.yaml")
    assert "design_trajectories" in rules_run(proc)
    before = {f.name: f.read_bytes() for f in (work / OUT).iterdir()}
    snakemake(work, "--cores", "2", "--configfile", "config/other.yaml")
    assert {f.name: f.read_bytes() for f in (work / OUT).iterdir()} == before
    assert len(list(work.glob("results/same_T4/design_trajectories/*/trajectories.nc"))) == 2


def test_committed_outputs_of_another_profile_are_refused(base, tmp_path):
    work = _copy(base, tmp_path / "guard")
    (work / OUT / "provenance.json").write_text('{"config_file": "config/tables.yaml"}\n')
    proc = snakemake(work, *ARGS, "-n", check=False)
    assert proc.returncode != 0
    assert "holds the committed outputs of config/tables.yaml" in proc.stdout + proc.stderr


def test_a_run_naming_its_targets_remakes_a_stale_table(base, tmp_path):
    """``make tables`` names its files: after an edit of the tables' code the named table is
    remade too (its stamp is stale), and a dry run first deletes nothing."""
    work = _copy(base, tmp_path / "named")
    _append("workflow/ssmobs/reports/tables.py", "\n# an edit of the tables' code\n")(work)
    table = f"{OUT}/table2_joint_vs_marginal.csv"
    named = [table, "--cores", "2", "--configfile", CONFIG]
    snakemake(work, "-n", *named)
    assert (work / table).is_file(), "a dry run deleted a table"
    ran = rules_run(snakemake(work, *named))
    assert ran == {"paper_tables"}, ran
    assert (work / table).read_bytes() == (base / table).read_bytes()
    again = snakemake(work, "-n", *named)
    assert "Nothing to be done" in again.stdout + again.stderr


def test_a_refused_second_run_removes_nothing(base, tmp_path):
    """Found before (issue 35): while one run worked, a second one with another config
    (its Figure 2 edited) in the same directory was refused by Snakemake's lock only after
    its parse had deleted the first run's Figure 2 and stamp, and advised ``--unlock``."""
    work = _copy(base, tmp_path / "concurrent")
    write_config(work, _set("scenarios.0.omega.a", 0.8))  # the first run: every stage
    other = yaml.safe_load(yaml.safe_dump(BASE))
    other["figure2"] = {"a": 0.5}
    (work / "config" / "other.yaml").write_text(yaml.safe_dump(other))
    # Figure 2 and its stamp: stale for the second config, untouched by the first run
    kept = [*(work / OUT).glob("fig2_design_points.*"), *work.glob("results/**/fig*points.key")]
    assert len(kept) == 3
    before = {p: (p.stat().st_mtime_ns, p.read_bytes()) for p in kept}
    first = subprocess.Popen(
        [sys.executable, "-m", "snakemake", *ARGS],
        cwd=work,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    try:
        start = time.monotonic()
        while not list((work / ".snakemake" / "locks").glob("*")):
            assert first.poll() is None, "the first run ended before it took its lock"
            assert time.monotonic() - start < 600, "the first run took no lock"
            time.sleep(0.1)
        second = snakemake(work, "--cores", "2", "--configfile", "config/other.yaml", check=False)
        assert first.poll() is None, "the first run ended before the second was refused"
    finally:
        out, _ = first.communicate(timeout=3600)
    text = second.stdout + second.stderr
    assert second.returncode != 0
    # refused by the run lock, taken before any tidying (issue 61), in one line
    line = f"another run of this workflow works in this directory (PID {first.pid})"
    assert f"{line}: this run stops before it removes or writes anything" in text, text[-3000:]
    assert "--unlock" not in text
    assert {p: (p.stat().st_mtime_ns, p.read_bytes()) for p in kept} == before
    assert first.returncode == 0, out[-3000:]
    again = snakemake(work, *ARGS, "-n")
    assert "Nothing to be done" in again.stdout + again.stderr
