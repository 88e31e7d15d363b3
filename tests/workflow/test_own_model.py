"""docs/your-own-model.md, step by step, on a fresh copy of the repository.

The tutorial's listings are the repository's files (so the tutorial cannot drift from the
code), its check command passes, and the two mistakes it shows stop the run with the message
it quotes, before any NUTS run of the model.  Its quick run on the smoke profile is checked
in test_smoke.py, on the session's smoke run (so that this module need not wait for it).
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest
from factories import same_a09
from helpers import REPO, make_workdir, only, snakemake

pytestmark = pytest.mark.workflow

TUTORIAL = REPO / "docs" / "your-own-model.md"
TARGET = "paper_figures/smoke/ours_stoch_vol_observability.png"


def listing(path: str) -> str:
    """The fenced block that follows the line naming ``path`` in the tutorial."""
    text = TUTORIAL.read_text()
    m = re.search(rf"^`{re.escape(path)}`:?\s*\n+```[a-z]*\n(.*?)^```", text, flags=re.M | re.S)
    assert m, f"no listing of {path} in the tutorial"
    return m.group(1)


@pytest.mark.parametrize("path", ["workflow/ssmobs/models/stoch_vol.py", "stan/stoch_vol.stan"])
def test_listings_are_the_repository_files(path):
    assert listing(path) == (REPO / path).read_text()


def test_config_entry_in_tutorial_is_the_config():
    text = TUTORIAL.read_text()
    for line in (REPO / "config" / "stoch_vol.yaml").read_text().splitlines():
        if line.startswith("  - {name: stoch_vol_T20"):
            assert line in text


def _python(workdir, *args):
    env = {**os.environ, "PYTHONPATH": str(workdir / "workflow")}
    return subprocess.run(
        [sys.executable, *args], cwd=workdir, env=env, capture_output=True, text=True, timeout=900
    )


@pytest.fixture(scope="module")
def fresh(tmp_path_factory):
    return make_workdir(tmp_path_factory.mktemp("own_model"))


@pytest.fixture(autouse=True)
def copy_package_first(monkeypatch, request):
    """Snakemake's jobs import ssmobs from the copy (not from a PYTHONPATH of the caller)."""
    work = None
    for name in ("fresh", "tmp_path"):
        if name in request.fixturenames:
            work = request.getfixturevalue(name)
            break
    if work is not None:
        monkeypatch.setenv("PYTHONPATH", str(work / "workflow"))


def test_step_check_command(fresh):
    proc = _python(
        fresh, "-m", "ssmobs.model_check", "stoch_vol", "--configfile", "config/stoch_vol.yaml"
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "model 'stoch_vol': Python model and Stan program agree" in proc.stdout


def test_step_study_command_makes_every_output(tmp_path):
    """The tutorial's study command is one command for every output of a config (issue 19:
    it once ran only check_model and reported success): here on a one-scenario study."""
    import yaml

    work = make_workdir(tmp_path)
    conf = yaml.safe_load((work / "config" / "stoch_vol.yaml").read_text())
    conf["outputs_dir"] = "paper_figures/mine"
    conf["scenarios"] = [{**conf["scenarios"][0], "T": 4, "K": 2}]
    conf["observability_studies"] = [{"name": "mine", "scenarios": [conf["scenarios"][0]["name"]]}]
    conf["stan"] = {**conf.get("stan", {}), "chains": 2, "iter_warmup": 100, "iter_sampling": 100}
    (work / "config" / "mine.yaml").write_text(yaml.safe_dump(conf))
    # what `make run CONFIG=config/mine.yaml` runs after its set-up: no target named
    snakemake(work, "--cores", "2", "--rerun-incomplete", "--configfile", "config/mine.yaml")
    out = work / "paper_figures" / "mine"
    for name in ("ours_mine_observability.csv", "ours_mine_observability.png"):
        assert (out / name).stat().st_size > 0, name
    # the study's outputs only: none of the paper's tables and figures (issue 36)
    assert sorted(p.name for p in out.iterdir()) == [
        f"ours_mine_observability.{ext}" for ext in ("csv", "md", "png")
    ]


@pytest.mark.slow  # compiles the swapped program, then the check names the mistake (issue 48)
def test_mistake_swapped_stan_parameters(tmp_path):
    work = make_workdir(tmp_path)
    stan = work / "stan" / "stoch_vol.stan"
    code = stan.read_text()
    phi = "  real<lower=phi_lower, upper=phi_upper> phi;  // persistence of the log-variance\n"
    sigma = "  real<lower=sigma_lo, upper=sigma_upper> sigma;  // volatility of the log-variance\n"
    assert phi + sigma in code
    stan.write_text(code.replace(phi + sigma, sigma + phi))
    proc = snakemake(work, "--cores", "1", TARGET, "--configfile", "config/smoke.yaml", check=False)
    assert proc.returncode != 0
    log = only(work, "results/stoch_vol_T5/check_model_stan/*.log").read_text()
    assert (
        "the parameters block declares ['sigma', 'phi', 'x0', 'x'], but the Python model "
        "'stoch_vol' (param_names = ['phi', 'sigma']) needs exactly ['phi', 'sigma', 'x0', "
        "'x'] in this order"
    ) in log
    assert not (work / "results" / "stoch_vol_T5" / "sample_nuts").exists()  # no NUTS run


def test_mistake_copied_module_keeps_the_old_slug(tmp_path):
    work = make_workdir(tmp_path)
    models = work / "workflow" / "ssmobs" / "models"
    shutil.copy(models / "stoch_vol.py", models / "my_model.py")
    proc = snakemake(
        work, "-n", "--cores", "1", TARGET, "--configfile", "config/smoke.yaml", check=False
    )
    assert proc.returncode != 0
    assert (
        "slug 'stoch_vol' is used twice: by my_model.py (StochVol) and stoch_vol.py (StochVol)"
    ) in proc.stdout + proc.stderr


def swapped_growth() -> str:
    """The growth test model (tests/growth_model.py) as a model module of its own, slug
    "growth", with a planted mistake: ``b, a = omega`` swapped in simulate (issue 36)."""
    text = (Path(__file__).resolve().parents[1] / "growth_model.py").read_text()
    for right, wrong in (
        ('slug = "test_growth"', 'slug = "growth"'),
        ("a, b = omega\n        K", "b, a = omega\n        K"),
    ):
        assert text.count(right) == 1, right
        text = text.replace(right, wrong)
    return text


def test_mistake_swapped_simulate_is_the_models_error_on_the_workflow_path(tmp_path):
    """`b, a = omega` swapped in simulate: `make run CONFIG=...` (its preflight, then
    Snakemake with --configfile) names the model's mistake, not the config's true values,
    whose noise-free trajectory the wrong simulate blows up to |x_t| = 4.3e+52 (issue 36)."""
    import yaml

    work = make_workdir(tmp_path)
    (work / "workflow" / "ssmobs" / "models" / "growth.py").write_text(swapped_growth())
    conf = {
        "outputs_dir": "paper_figures/growth",
        "scenarios": [
            {
                "name": "growth_T20",
                "model": "growth",
                "omega": {"a": 0.5, "b": 25},
                "x0": 0.1,
                "T": 20,
                "K": 4,
                "stan": False,
            }
        ],
    }
    (work / "config" / "growth.yaml").write_text(yaml.safe_dump(conf))
    preflight = _python(work, "-m", "ssmobs.config.preflight", "config/growth.yaml")
    dry = snakemake(work, "-n", "--configfile", "config/growth.yaml", check=False)
    for proc in (preflight, dry):
        text = proc.stdout + proc.stderr
        assert proc.returncode != 0
        assert "model 'growth' fails its own check" in text, text[-3000:]
        assert "simulate does not match the transition term" in text
        assert "check the order of the parameters in simulate" in text
        assert "reach |x_t|" not in text


def _planned(proc) -> set[str]:
    """Every output file of the jobs a dry run plans."""
    from helpers import logged_units

    text = proc.stdout + "\n" + proc.stderr
    return {f for unit in logged_units(text) for job in unit.jobs for f in job.output}


#: the paper's tables and figures, as a config that asks for them gets them
PAPER_STEMS = (
    "fig2_design_points",
    "fig3_joint_vs_marginal",
    "fig_observability_ratios",
    "table2_joint_vs_marginal",
    "table3_coverage",
    "section4_summary",
    "table_mu0_sweep",
    "table_k_selection",
    "table_convergence_sensitivity",
)


def test_a_study_config_plans_its_study_outputs_only(tmp_path):
    """An own study (no scenario of the paper, no paper_outputs) gets its study's table and
    figure and none of the paper's ~30 files; naming one scenario of the paper (its
    paper_ref) brings them back, in the same outputs_dir (issue 36)."""
    import yaml

    work = make_workdir(tmp_path)
    conf = yaml.safe_load((work / "config" / "stoch_vol.yaml").read_text())
    conf["outputs_dir"] = "paper_figures/mine"
    (work / "config" / "mine.yaml").write_text(yaml.safe_dump(conf))
    proc = snakemake(work, "-n", "--configfile", "config/mine.yaml")
    mine = sorted(f for f in _planned(proc) if f.startswith("paper_figures/"))
    assert mine == [
        f"paper_figures/mine/ours_stoch_vol_observability.{ext}" for ext in ("csv", "md", "png")
    ]
    assert "outputs_dir is not set" not in proc.stdout + proc.stderr
    same = same_a09(name="same_T4")
    conf["scenarios"].append({**same, "stan": False, "paper_ref": "same_a09_T4"})
    (work / "config" / "mine.yaml").write_text(yaml.safe_dump(conf))
    planned = _planned(snakemake(work, "-n", "--configfile", "config/mine.yaml"))
    stems = {Path(f).stem for f in planned if f.startswith("paper_figures/mine/")}
    assert set(PAPER_STEMS) <= stems and "ours_stoch_vol_observability" in stems


def test_a_config_without_outputs_dir_says_where_its_outputs_go(tmp_path):
    """No outputs_dir: the tables and figures go to the top of paper_figures/, and the run
    says so in one line (once), naming the config file (issue 36)."""
    import yaml

    work = make_workdir(tmp_path)
    conf = yaml.safe_load((work / "config" / "stoch_vol.yaml").read_text())
    del conf["outputs_dir"]
    (work / "config" / "mine.yaml").write_text(yaml.safe_dump(conf))
    proc = snakemake(work, "-n", "--configfile", "config/mine.yaml")
    lines = [l for l in (proc.stdout + proc.stderr).splitlines() if "outputs_dir is not set" in l]
    assert lines == [
        "outputs_dir is not set in config/mine.yaml: its tables and figures go to the top of "
        "paper_figures/, beside the committed profiles' folders; set outputs_dir (e.g. "
        "paper_figures/my_study) to give them a folder of their own"
    ]
    assert "paper_figures/ours_stoch_vol_observability.png" in _planned(proc)


def test_smoke_of_ones_own_study_plans_its_jobs_on_small_sizes(tmp_path):
    """`make smoke CONFIG=config/stoch_vol.yaml`: the overlay (the smoke profile's sizes)
    plans every stage of the study's three scenarios, K = 4 each, and writes its tables and
    figures to paper_figures/smoke_stoch_vol/, never to the study's committed folder."""
    work = make_workdir(tmp_path)
    overlay = "results/smoke_configs/stoch_vol.yaml"
    made = _python(work, "-m", "ssmobs.config.smoke", "config/stoch_vol.yaml", "--out", overlay)
    assert made.returncode == 0, made.stderr
    proc = snakemake(work, "-n", "--configfile", overlay)
    text = proc.stdout + "\n" + proc.stderr
    from helpers import logged_units

    jobs = [job for unit in logged_units(text) for job in unit.jobs]
    scenarios = ("stoch_vol_T20", "stoch_vol_T50", "stoch_vol_T100")
    for rule in ("check_model", "design_trajectories", "joint_map", "sample_nuts", "gather_nuts"):
        planned = {f.split("/")[1] for job in jobs if job.rule == rule for f in job.output}
        assert planned == set(scenarios), (rule, planned)
    outputs = sorted(f for job in jobs for f in job.output if f.startswith("paper_figures/"))
    assert outputs == [
        f"paper_figures/smoke_stoch_vol/ours_stoch_vol_observability.{ext}"
        for ext in ("csv", "md", "png")
    ]
    nuts = [job for job in jobs if job.rule == "sample_nuts"]
    assert len(nuts) == 3  # one batch of the K = 4 trajectories per scenario


NO_STAN_CONFIG = """outputs_dir: paper_figures/ns
scenarios:
  - {name: ns_T4, model: %s, omega: {a: 0.9}, x0: 8, T: 4, K: 4, prior: restricted, stan: %s}
paper_outputs: {tables_2_3: [], figure3: [], figure4: null}
k_selection: []
observability_studies: []
"""


@pytest.mark.slow  # stan: false; a dry run plans a generated program (rare path; issue 48)
def test_own_model_without_stan_program_gets_a_generated_one(tmp_path):
    """A model module without stan/<slug>.stan: with ``stan: false`` no Stan job is planned
    (issue 46: once a traceback at the parse); with ``stan: true`` its program is generated
    (issue 49), so the check against Stan and the NUTS runs are planned, no file in stan/."""
    work = make_workdir(tmp_path)
    models = work / "workflow" / "ssmobs" / "models"
    (models / "nostan.py").write_text(
        'from .same import Same\n\n\nclass NoStan(Same):\n    slug = "nostan"\n'
    )
    (work / "config" / "ns.yaml").write_text(NO_STAN_CONFIG % ("nostan", "false"))
    rules = _planned_rules(snakemake(work, "-n", "--configfile", "config/ns.yaml"))
    assert {"joint_map", "design_trajectories"} <= rules
    assert not rules & {"check_model_stan", "build_stan_model", "sample_nuts"}
    (work / "config" / "ns.yaml").write_text(NO_STAN_CONFIG % ("nostan", "true"))
    planned = _planned(snakemake(work, "-n", "--configfile", "config/ns.yaml"))
    for stage in ("check_model_stan", "sample_nuts", "gather_nuts"):
        assert any(f.startswith(f"results/ns_T4/{stage}/") for f in planned), stage
    assert any(f.startswith("results/shared/stan/native/nostan/") for f in planned)
    assert not (work / "stan" / "nostan.stan").exists()


CONSTRAINED_CONFIG = """outputs_dir: paper_figures/nc
scenarios:
  - {name: nc_T4, model: %s, omega: {a: 0.6, b: 0.5, c: 0.9, d: 0.9}, x0: [8, 8], T: 4, K: 4,
     prior: restricted, stan: %s}
paper_outputs: {tables_2_3: [], figure3: [], figure4: null}
k_selection: []
observability_studies: []
"""


@pytest.mark.slow  # a refusal before any job (a rare path; issue 48)
def test_own_model_with_support_constraints_needs_its_stan_program(tmp_path):
    """Support constraints (here a^2 + b^2 < 1) are no parameter bounds, so no program is
    generated for them: one line naming the constraint, before any job; ``stan: false``
    runs."""
    work = make_workdir(tmp_path)
    models = work / "workflow" / "ssmobs" / "models"
    (models / "nocon.py").write_text(
        'from .sep_d1_p2 import SepD1P2\n\n\nclass NoCon(SepD1P2):\n    slug = "nocon"\n'
    )
    (work / "config" / "nc.yaml").write_text(CONSTRAINED_CONFIG % ("nocon", "false"))
    snakemake(work, "-n", "--configfile", "config/nc.yaml")
    (work / "config" / "nc.yaml").write_text(CONSTRAINED_CONFIG % ("nocon", "true"))
    for cmd in (
        [sys.executable, "-m", "ssmobs.config.preflight", "config/nc.yaml"],
        [sys.executable, "-m", "snakemake", "-n", "--configfile", "config/nc.yaml"],
    ):
        out = subprocess.run(
            cmd,
            cwd=work,
            capture_output=True,
            text=True,
            env={**os.environ, "PYTHONPATH": str(work / "workflow")},
        )
        text = out.stdout + out.stderr
        assert out.returncode != 0 and "Traceback" not in text
        lines = [line for line in text.splitlines() if "support constraints" in line]
        assert len(lines) == 1, text[-3000:]
        assert "model 'nocon' has support constraints (a^2 + b^2 < 1)" in lines[0]
        assert "write stan/nocon.stan by hand" in lines[0]
        assert "or set stan: false for this scenario" in lines[0]


def one_file_model(work: Path) -> str:
    """The tutorial's model as a one-file model of its own (slug "sv_one_file"): its module
    copied under another name, no Stan program."""
    text = (work / "workflow" / "ssmobs" / "models" / "stoch_vol.py").read_text()
    assert text.count('slug = "stoch_vol"') == 1
    text = text.replace('slug = "stoch_vol"', 'slug = "sv_one_file"')
    text = text.replace("class StochVol(", "class SvOneFile(")
    (work / "workflow" / "ssmobs" / "models" / "sv_one_file.py").write_text(text)
    assert not (work / "stan" / "sv_one_file.stan").exists()
    return "sv_one_file"


def test_one_file_model_runs_through_nuts(tmp_path):
    """issue 49: a model in one Python file, no Stan program: the model check checks the
    generated program (against the Python model's log density and gradient), NUTS runs it,
    the gathered summary counts every trajectory; the old stan/ path is not touched."""
    import json

    import yaml

    work = make_workdir(tmp_path)
    slug = one_file_model(work)
    conf = yaml.safe_load((work / "config" / "stoch_vol.yaml").read_text())
    entry = {**conf["scenarios"][0], "name": "one_T10", "model": slug, "T": 10, "K": 3}
    conf = {
        "outputs_dir": "paper_figures/one",
        "scenarios": [entry],
        "observability_studies": [{"name": "one", "scenarios": ["one_T10"]}],
        "stan": {"chains": 2, "iter_warmup": 150, "iter_sampling": 150},
    }
    (work / "config" / "one.yaml").write_text(yaml.safe_dump(conf))
    proc = snakemake(work, "--cores", "2", "--configfile", "config/one.yaml")
    assert proc.returncode == 0
    report = json.loads(only(work, "results/one_T10/check_model_stan/*.json").read_text())
    assert report["ok"]
    assert any(
        c.startswith("generated gradients: equal to the Python model's") for c in report["checks"]
    )
    summary = json.loads(only(work, "results/one_T10/gather_nuts/*/summary.json").read_text())
    assert summary["model"] == slug
    frame = pd.read_parquet(only(work, "results/one_T10/gather_nuts/*/marginal_map.parquet"))
    assert frame["k"].tolist() == [0, 1, 2]
    records = sorted(work.glob("results/one_T10/sample_nuts/records/*/k*.json"))
    assert len(records) == 3
    # every record ran the generated program with its C++ header
    assert all(json.loads(r.read_text())["status"] == "ok" for r in records)
    assert (work / "paper_figures" / "one" / "ours_one_observability.csv").stat().st_size > 0
    # a cleared program cache (issue 62): the marker stays in results/, the generated program
    # it names is gone; the run removes the marker, the build job writes the program again
    # and the model check and the batches run it
    marker = only(work, f"results/shared/stan/native/{slug}/*.json")
    built = json.loads(marker.read_text())
    programs = [Path(built[k]) for k in ("program_file", "header_file")]
    for path in programs:
        path.unlink()
    proc = snakemake(work, "--cores", "2", "--configfile", "config/one.yaml")
    said = f"made again, not reused: {marker.relative_to(work)} names files of its Stan program"
    assert said in proc.stdout + proc.stderr
    assert all(path.is_file() for path in programs)
    assert json.loads(marker.read_text()) == built
    assert json.loads(only(work, "results/one_T10/check_model_stan/*.json").read_text())["ok"]


@pytest.mark.slow  # a model module with a syntax error (a rare path; issue 48)
def test_a_broken_model_module_stops_only_the_configs_that_use_it(tmp_path):
    """Found before (issue 46): a model file with a syntax error gave a 29-line traceback
    for every config, also those that do not use it."""
    work = make_workdir(tmp_path)
    (work / "workflow" / "ssmobs" / "models" / "broken.py").write_text("def broken(:\n")
    (work / "config" / "ns.yaml").write_text(NO_STAN_CONFIG % ("same", "false"))
    snakemake(work, "-n", "--configfile", "config/ns.yaml")
    (work / "config" / "ns.yaml").write_text(NO_STAN_CONFIG % ("broken", "false"))
    proc = snakemake(work, "-n", "--configfile", "config/ns.yaml", check=False)
    text = proc.stdout + proc.stderr
    assert proc.returncode != 0 and "Traceback" not in text
    assert "broken.py: import failed: SyntaxError" in text
    assert "configs that do not use model 'broken' run" in text


def _planned_rules(proc) -> set[str]:
    return set(re.findall(r"^(?:local)?rule (\w+):$", proc.stdout + proc.stderr, flags=re.M))
