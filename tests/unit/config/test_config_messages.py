"""Many scenarios with the same problem give one line per kind of problem (issue 35, item 5).

Found before: a config of 50 large scenarios gave one message per scenario and job kind
(about 100-250 lines); one scenario's message must stay exactly as it was.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from factories import same_a09
from repo_paths import WORKFLOW_DIR
from ssmobs.config import validation as cfg

pytestmark = pytest.mark.unit


def scenarios(n: int, **changes) -> list[dict]:
    """``n`` large scenarios of model Same (each over the memory limit in two job kinds)."""
    base = same_a09(name=None, T=400, K=200_000)
    return [{"name": f"big_scenario_{i:02d}", **base, **changes} for i in range(n)]


def config_of(entries: list[dict]) -> dict:
    return {
        "outputs_dir": "paper_figures/big",
        "scenarios": entries,
        "paper_outputs": {"tables_2_3": [], "figure3": [], "figure4": None},
    }


def problem_lines(config: dict, **kwargs) -> list[str]:
    with pytest.raises(cfg.ConfigError) as err:
        cfg.validate(config, **kwargs)
    return str(err.value).splitlines()


def test_fifty_large_scenarios_give_a_short_message_naming_the_count():
    lines = problem_lines(config_of(scenarios(50)))
    text = "\n".join(lines)
    assert len(lines) <= 20, text
    # one line per kind: the design sets' memory, gather_nuts' memory, the number of jobs,
    # the joint-MAP starts' CPU hours
    memory = [x for x in lines if "design_disturbances job needs" in x]
    assert len(memory) == 1, text
    assert memory[0].startswith("  - 50 scenarios alike, the first: scenario 'big_scenario_00'")
    others = "the others: 'big_scenario_01', 'big_scenario_02', 'big_scenario_03' and 46 more"
    assert others in memory[0]
    assert len([x for x in lines if "gather_nuts job needs" in x]) == 1
    assert "every one: .venv/bin/python -m ssmobs.config.preflight --all CONFIGFILE" in lines[0]
    assert "(102 problems of 4 kinds" in lines[0]
    assert len([x for x in lines if "joint-MAP starts of the run would take" in x]) == 1


def test_values_that_differ_are_still_one_kind():
    """Each scenario's true value is out of range by another amount: one kind, one line."""
    entries = scenarios(50, T=4, K=10)
    for i, sc in enumerate(entries):
        sc["omega"] = {"a": 1.0 + i / 10}
    lines = problem_lines(config_of(entries))
    assert len(lines) == 2, lines
    first = "  - 50 scenarios alike, the first: scenarios[0] ('big_scenario_00')"
    assert lines[1].startswith(first)
    assert "true value a=1.0 must satisfy |a| < 1 in model 'same'" in lines[1]


def test_schema_problems_of_many_scenarios_name_them_by_their_names():
    """The schema's own messages give only the index (scenarios[3].K); the line names them."""
    entries = scenarios(30, T=4, K=10.0)
    lines = problem_lines(config_of(entries))
    assert len(lines) == 2, lines
    assert lines[1].startswith("  - 30 scenarios alike, the first: scenarios[0].K = 10.0")
    others = "the others: 'big_scenario_01', 'big_scenario_02', 'big_scenario_03' and 26 more"
    assert others in lines[1]


def test_one_scenarios_messages_are_given_as_before():
    lines = problem_lines(config_of(scenarios(1)))
    assert lines[0] == "invalid configuration:"
    assert lines[1] == (
        "  - scenario 'big_scenario_00': a design_disturbances job needs about 36.3 GiB of "
        "memory (K = 200000, T = 400, q = 800, design), more than limits.job_memory_gib = "
        "10 GiB; reduce the sizes or raise the limit (config/README.md, section 'limits')"
    )
    assert len(lines) == 4  # and the gather_nuts job's, and the joint-MAP starts' hours
    assert lines[3].startswith("  - the joint-MAP starts of the run would take about")


def test_three_alike_are_still_given_one_by_one():
    lines = problem_lines(config_of(scenarios(3, T=4, K=10, omega={"a": 2.0})))
    assert lines[0] == "invalid configuration:"
    assert [x.split(":")[0] for x in lines[1:]] == [
        f"  - scenarios[{i}] ('big_scenario_0{i}')" for i in range(3)
    ]


def test_every_problem_on_request():
    lines = problem_lines(config_of(scenarios(50)), every_problem=True)
    assert lines[0] == "invalid configuration:"
    assert len(lines) == 1 + 102


def run_preflight(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "ssmobs.config.preflight", *args],
        capture_output=True,
        text=True,
        cwd=cwd,
        env={"PYTHONPATH": str(WORKFLOW_DIR), "PATH": "/usr/bin:/bin"},
    )


def test_preflight_prints_the_summary_and_every_problem_with_all(tmp_path):
    path = tmp_path / "big.yaml"
    path.write_text(yaml.safe_dump(config_of(scenarios(50)), sort_keys=False))
    short = run_preflight(str(path), cwd=tmp_path)
    assert short.returncode == 1
    assert len(short.stderr.splitlines()) <= 20, short.stderr
    assert "50 scenarios alike" in short.stderr
    assert f"python -m ssmobs.config.preflight --all {path}" in short.stderr
    every = run_preflight("--all", str(path), cwd=tmp_path)
    assert every.returncode == 1
    assert len(every.stderr.splitlines()) == 1 + 102
    assert "scenario 'big_scenario_49': a gather_nuts job needs" in every.stderr


def test_analytic_gradients_with_pystan_is_one_line_naming_key_and_choices():
    conf = config_of([same_a09()])
    conf["stan"] = {"backend": "pystan", "gradients": "analytic"}
    lines = [ln for ln in problem_lines(conf) if "stan.gradients" in ln]
    assert len(lines) == 1
    assert "'analytic'" in lines[0] and "pystan" in lines[0] and "'autodiff'" in lines[0]
    conf["stan"]["gradients"] = "autodiff"
    cfg.validate(conf)
    conf["stan"] = {"backend": "native", "gradients": "analytic"}
    assert cfg.validate(conf)["stan"]["gradients"] == "analytic"
