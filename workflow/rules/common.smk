# Glue: config validation, target lists, input functions, wildcard constraints.
import re
import sys
from pathlib import Path

sys.path.insert(0, str(Path(workflow.basedir) / "workflow"))

from ssmobs import config as ssmobs_config  # noqa: E402
from ssmobs.config import ConfigError  # noqa: E402

try:
    ssmobs_config.validate(config)
except ConfigError as err:
    raise WorkflowError(str(err)) from None

SCENARIOS = {sc["name"]: sc for sc in config["scenarios"]}
REPO = Path(workflow.basedir)


wildcard_constraints:
    scenario="|".join(map(re.escape, SCENARIOS)) or "NONE",
    q=r"\d+",
    K=r"\d+",
    seed=r"\d+",
    method="design|random|antithetic",


def disturbance_path(q, K, method, seed):
    return f"results/shared/design_disturbances/q{q}_K{K}_{method}_seed{seed}.nc"


def scenario_disturbances(wildcards):
    sc = SCENARIOS[wildcards.scenario]
    return disturbance_path(ssmobs_config.disturbance_dim(sc), sc["K"], sc["method"], sc["seed"])


def figure2_disturbances(wildcards=None):
    f2 = config["figure2"]
    return disturbance_path(2, f2["K"], "design", f2["seed"])


def all_targets():
    targets = [f"results/{name}/design_trajectories/trajectories.nc" for name in SCENARIOS]
    targets += ["paper_figures/fig2_design_points.pdf", "paper_figures/fig2_design_points.png"]
    return targets
