"""Provenance of committed outputs: a run's wall and CPU time and its starting state."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest
from repo_paths import REPO_DIR
from ssmobs import provenance

pytestmark = pytest.mark.unit

CONFIG = "outputs_dir: out\nstan: {backend: pystan}\nscenarios: []\n"


def test_a_command_is_run_and_its_provenance_written(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "c.yaml").write_text(CONFIG)
    burn = "import time; t = time.process_time()\nwhile time.process_time() - t < 0.3: pass"
    code = provenance.main(
        ["--config", "c.yaml", "--outputs-dir", "out", "--", sys.executable, "-c", burn]
    )
    assert code == 0
    record = json.loads((tmp_path / "out" / "provenance.json").read_text())
    assert record["started_from_empty_results"] is True
    assert record["cpu_seconds"] >= 0.2
    assert record["wall_seconds"] >= record["cpu_seconds"] - 0.1
    assert record["config_file"] == "c.yaml"


def test_a_failed_command_writes_no_provenance(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "c.yaml").write_text(CONFIG)
    (tmp_path / "results" / "x").mkdir(parents=True)
    args = ["--config", "c.yaml", "--outputs-dir", "out", "--", sys.executable, "-c", "exit(3)"]
    assert provenance.main(args) == 3
    assert not (tmp_path / "out").exists()
    assert not provenance.results_empty(tmp_path / "results")


def test_a_run_made_before_is_recorded_with_its_measured_times(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "c.yaml").write_text(CONFIG)
    args = ["--config", "c.yaml", "--outputs-dir", "out", "--started", "1000", "--finished"]
    args += ["4175.2", "--cpu-seconds", "5977.8", "--from-empty-results", "yes"]
    assert provenance.main(args) == 0
    record = json.loads((tmp_path / "out" / "provenance.json").read_text())
    assert record["wall_seconds"] == 3175.2
    assert record["cpu_seconds"] == 5977.8
    assert record["started_from_empty_results"] is True
    assert record["date_utc"].startswith("1970-01-01T01:09:35")


def test_measured_times_are_refused_beside_a_command(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "c.yaml").write_text(CONFIG)
    args = ["--config", "c.yaml", "--outputs-dir", "out", "--cpu-seconds", "3", "--", "true"]
    with pytest.raises(SystemExit):
        provenance.main(args)
    assert not (tmp_path / "out").exists()


def test_the_outputs_folder_defaults_to_the_configs_outputs_dir(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "c.yaml").write_text(CONFIG)
    assert provenance.main(["--config", "c.yaml", "--", sys.executable, "-c", "pass"]) == 0
    assert json.loads((tmp_path / "out" / "provenance.json").read_text())["command"]


def test_provenance_records_what_the_numbers_depended_on():
    """CPU model and flags, the BLAS libraries with their kernel and threads, NumPy's
    dispatch, the versions (issue 34): as a job computes, not as this test process does."""
    from ssmobs import kernels, provenance

    numerics = provenance.numerics()
    assert numerics["cpu_model"] and numerics["cpu_flags"] and numerics["architecture"]
    assert numerics["numpy"] and numerics["scipy"] and numerics["settings"]
    assert numerics["blas"] and all(b["threads"] == 1 for b in numerics["blas"])
    assert len(numerics["blas"]) == 2  # NumPy's and SciPy's own OpenBLAS
    if kernels.covered():
        assert {b["kernel"] for b in numerics["blas"]} == {"Haswell"}
        assert not set(numerics["numpy_dispatch"]) & set(kernels.NUMPY_DISABLED)


def test_uncommitted_changes_name_the_files_outside_the_runs_outputs(tmp_path, monkeypatch):
    """A run in a worktree with changed tracked files records which (not only that some
    changed), leaving out the outputs folder the run itself writes."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "out").mkdir()
    (tmp_path / "other").mkdir()
    for path in ("c.yaml", "out/table.csv", "other/table.csv"):
        (tmp_path / path).write_text(CONFIG)
    for args in ("init -q", "add .", "-c user.name=t -c user.email=t@t commit -qm x"):
        subprocess.run(["git", *args.split()], check=True)
    assert provenance.uncommitted_files("out") == []
    (tmp_path / "out" / "table.csv").write_text("new")
    assert provenance.uncommitted_files("out") == []
    (tmp_path / "other" / "table.csv").write_text("new")
    assert provenance.uncommitted_files("out") == ["other/table.csv"]
    record = provenance.provenance("c.yaml", 0.0, 1.0, "cmd", outputs_dir="out")
    assert record["uncommitted_changes"] is True
    assert record["uncommitted_files"] == ["other/table.csv"]


def test_provenance_says_which_gradient_path_made_the_draws(monkeypatch):
    """``stan.gradients`` as set, else the schema's default, and per sampling model the path
    its program took (a model without ``stan/<model>.stan`` is always analytic); the paper
    profile samples with the analytic path (issue 63)."""
    from ssmobs.config.schema import load_schema
    from ssmobs.config.validation import read_config_file

    default = load_schema()["properties"]["stan"]["properties"]["gradients"]["default"]
    scenarios = [
        {"name": "a", "model": "same"},
        {"name": "b", "model": "sep", "stan": False},
        {"name": "c", "model": "my_own_model"},
    ]
    assert provenance.gradient_paths({"scenarios": scenarios}) == {
        "gradients": default,
        "gradients_by_model": {"my_own_model": "analytic", "same": default},
    }
    analytic = {"stan": {"gradients": "analytic"}, "scenarios": scenarios}
    autodiff = {"stan": {"gradients": "autodiff"}, "scenarios": scenarios}
    assert provenance.gradient_paths(analytic)["gradients_by_model"]["same"] == "analytic"
    assert provenance.gradient_paths(autodiff)["gradients_by_model"] == {
        "my_own_model": "analytic",
        "same": "autodiff",
    }
    paper = provenance.gradient_paths(read_config_file(REPO_DIR / "config" / "paper.yaml"))
    assert paper["gradients"] == "analytic"
    assert set(paper["gradients_by_model"].values()) == {"analytic"}
    assert len(paper["gradients_by_model"]) == 6
    monkeypatch.setattr(provenance, "numerics", lambda: {})
    record = provenance.provenance(REPO_DIR / "config" / "paper.yaml", 0.0, 1.0, "make paper")
    assert record["stan"]["gradients"] == "analytic"
    assert record["stan"]["gradients_by_model"] == paper["gradients_by_model"]
