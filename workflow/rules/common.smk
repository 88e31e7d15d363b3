# Glue: config validation, target lists, input functions, wildcard constraints.
import re
import sys
from pathlib import Path

sys.path.insert(0, str(Path(workflow.basedir) / "workflow"))

from ssmobs import config as ssmobs_config  # noqa: E402
from ssmobs.config import ConfigError  # noqa: E402
from ssmobs.models import ModelDefinitionError  # noqa: E402
from ssmobs import stages  # noqa: E402

try:
    ssmobs_config.validate(config)  # also finds and checks every model module
except (ConfigError, ModelDefinitionError) as err:
    raise WorkflowError(str(err)) from None

SCENARIOS = {sc["name"]: sc for sc in config["scenarios"]}
KSEL = {ks["name"]: ks for ks in config["k_selection"]}
STUDIES = {st["name"]: st for st in config["observability_studies"]}
REPO = Path(workflow.basedir)
JOINT_SCENARIOS = [n for n, sc in SCENARIOS.items() if sc["joint_map"]]
STAN_SCENARIOS = [n for n, sc in SCENARIOS.items() if sc["stan"]]
TABLE_II_SCENARIOS = [sc["name"] for sc in stages.table_ii_scenarios(config["scenarios"])]


def joint_summary(name):
    return f"results/{name}/joint_map/summary.json"


def stan_summary(name):
    return f"results/{name}/gather_nuts/summary.json"


wildcard_constraints:
    scenario="|".join(map(re.escape, SCENARIOS)) or "NONE",
    ksel="|".join(map(re.escape, KSEL)) or "NONE",
    study="|".join(map(re.escape, STUDIES)) or "NONE",
    q=r"\d+",
    K=r"\d+",
    seed=r"\d+",
    method="design|random|antithetic",
    batch=r"\d+",
    model="|".join(sorted({sc["model"] for sc in config["scenarios"]})) or "NONE",


def disturbance_path(q, K, method, seed):
    return f"results/shared/design_disturbances/q{q}_K{K}_{method}_seed{seed}.nc"


def model_check(wildcards):
    """The check of the scenario's model (rule check_model), needed before its trajectories.

    ancient: a check rerun because a scenario of the model was added (new check case) must
    not make the trajectories of the other scenarios out of date."""
    return ancient(f"results/shared/check_model/{SCENARIOS[wildcards.scenario]['model']}.json")


def study_scenarios(name):
    """The scenario entries of one observability study, in config order."""
    return [SCENARIOS[n] for n in STUDIES[name]["scenarios"]]


def scenario_disturbances(wildcards):
    sc = SCENARIOS[wildcards.scenario]
    return disturbance_path(ssmobs_config.disturbance_dim(sc), sc["K"], sc["method"], sc["seed"])


def k_selection_disturbances(wildcards):
    sc = SCENARIOS[KSEL[wildcards.ksel]["scenario"]]
    q = ssmobs_config.disturbance_dim(sc)
    return disturbance_path(q, wildcards.K, wildcards.method, wildcards.seed)


def k_selection_points(ks):
    """Every (method, seed, K_i) summary of one k_selection entry (design uses its first seed)."""
    out = []
    for method in ks["methods"]:
        seeds = ks["seeds"][:1] if method == "design" else ks["seeds"]
        for seed in seeds:
            out += [f"results/k_selection/{ks['name']}/{method}_seed{seed}/K{K}.json"
                    for K in ks["K_grid"]]
    return out


def nuts_batches(wildcards):
    from ssmobs.stages import batches

    sc = SCENARIOS[wildcards.scenario]
    n = len(batches(sc["K"], config["stan"]["batch_size"]))
    return [f"results/{wildcards.scenario}/sample_nuts/batch{b}.parquet" for b in range(n)]


def figure2_disturbances(wildcards=None):
    f2 = config["figure2"]
    return disturbance_path(2, f2["K"], "design", f2["seed"])


def all_targets():
    targets = [f"results/{name}/design_trajectories/trajectories.nc" for name in SCENARIOS]
    targets += [f"results/{name}/joint_map/summary.json" for name, sc in SCENARIOS.items()
                if sc["joint_map"]]
    targets += [f"results/{name}/gather_nuts/summary.json" for name, sc in SCENARIOS.items()
                if sc["stan"]]
    for name in KSEL:
        targets += expand(f"paper_figures/fig_k_convergence_{name}.{{ext}}", ext=["pdf", "png"])
    if KSEL:
        targets += expand("paper_figures/table_k_selection.{ext}", ext=["csv", "md", "tex"])
    profile = stages.profile_scenario(config["scenarios"])
    if profile is not None:
        targets += expand(f"paper_figures/fig4_profile_posterior_{profile['name']}.{{ext}}",
                          ext=["pdf", "png"])
    for name in STUDIES:
        targets += expand(f"paper_figures/ours_{name}_observability.{{ext}}",
                          ext=["csv", "md", "png"])
    targets += ["paper_figures/fig2_design_points.pdf", "paper_figures/fig2_design_points.png"]
    targets += expand("paper_figures/{stem}.{ext}", ext=["csv", "md", "tex"],
                      stem=["table2_joint_vs_marginal", "table3_coverage", "section4_summary"])
    targets += expand("paper_figures/{stem}.{ext}", ext=["pdf", "png"],
                      stem=["fig3_joint_vs_marginal", "fig_observability_ratios"])
    return targets
