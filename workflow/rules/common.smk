# Glue: config validation, target lists, input functions, wildcard constraints.
import re
import sys
from pathlib import Path

sys.path.insert(0, str(Path(workflow.basedir) / "workflow"))

from ssmobs import config as ssmobs_config  # noqa: E402
from ssmobs.config import ConfigError  # noqa: E402
from ssmobs.models import ModelDefinitionError  # noqa: E402
from ssmobs.scenario import Scenario  # noqa: E402
from ssmobs import stages  # noqa: E402
from ssmobs.stan_backends import resolve_backend  # noqa: E402

try:
    ssmobs_config.validate(config)  # also finds and checks every model module
except (ConfigError, ModelDefinitionError) as err:
    files = ", ".join(map(str, workflow.configfiles)) or "(none)"
    raise WorkflowError(f"config file(s) {files}: {err}") from None

try:  # "auto" is resolved here, so the concrete backend is part of the rules' params
    STAN_BACKEND = resolve_backend(config["stan"]["backend"])
except ValueError as err:
    raise WorkflowError(str(err)) from None

#: where the tables and figures go (config key outputs_dir)
OUT = config["outputs_dir"]
SCENARIOS = {sc["name"]: sc for sc in config["scenarios"]}
#: the same entries as typed objects (the rules pass the plain entries above as params)
SCENARIO_OBJECTS = {name: Scenario.from_config(sc) for name, sc in SCENARIOS.items()}
KSEL = {ks["name"]: ks for ks in config["k_selection"]}
STUDIES = {st["name"]: st for st in config["observability_studies"]}
REPO = Path(workflow.basedir)
JOINT_SCENARIOS = [n for n, sc in SCENARIOS.items() if sc["joint_map"]]
STAN_SCENARIOS = [n for n, sc in SCENARIOS.items() if sc["stan"]]
MU0_SCENARIOS = [
    n
    for n, sc in SCENARIOS.items()
    if sc["joint_map"] and sc["model"] in config["mu0_sweep"]["models"]
]
#: the scenarios the paper's tables and figures show (config key paper_outputs)
TABLE_II_SCENARIOS = list(config["paper_outputs"]["tables_2_3"])
FIGURE3_SCENARIOS = list(config["paper_outputs"]["figure3"])
FIGURE4_SCENARIO = config["paper_outputs"]["figure4"]
EXACT_SCENARIOS = [n for n, sc in SCENARIO_OBJECTS.items() if sc.exact_applies]
EXACT_VS_STAN_SCENARIOS = [n for n in EXACT_SCENARIOS if SCENARIOS[n]["stan"]]


def joint_summary(name):
    return f"results/{name}/joint_map/summary.json"


def stan_summary(name):
    return f"results/{name}/gather_nuts/summary.json"


def exact_table(name, K):
    return f"results/{name}/exact_marginal/K{K}/marginal_map.parquet"


def exact_summary_path(name):
    """Summary of the exact stage at the scenario's exact_K (the one the tables show)."""
    return (
        f"results/{name}/exact_marginal/K{SCENARIO_OBJECTS[name].exact_trajectories}/summary.json"
    )


def exact_trajectories(wildcards):
    """The scenario's design trajectories when K is its own K, else those at K."""
    sc = SCENARIOS[wildcards.scenario]
    if int(wildcards.K) == sc["K"]:
        return f"results/{wildcards.scenario}/design_trajectories/trajectories.nc"
    return f"results/{wildcards.scenario}/exact_marginal/K{wildcards.K}/trajectories.nc"


def exact_disturbances(wildcards):
    sc = SCENARIO_OBJECTS[wildcards.scenario]
    return disturbance_path(sc.disturbance_dim, wildcards.K, sc.method, sc.seed)


wildcard_constraints:
    scenario="|".join(map(re.escape, SCENARIOS)) or "NONE",
    ksel="|".join(map(re.escape, KSEL)) or "NONE",
    study="|".join(map(re.escape, STUDIES)) or "NONE",
    q=r"\d+",
    K=r"\d+",
    seed=r"\d+",
    method="design|random|antithetic",
    sets="independent|nested",
    batch=r"\d+",
    backend="native|cmdstanpy|pystan",
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
    sc = SCENARIO_OBJECTS[wildcards.scenario]
    return disturbance_path(sc.disturbance_dim, sc.K, sc.method, sc.seed)


def k_selection_disturbances(wildcards):
    from ssmobs.k_selection import set_seed

    q = SCENARIO_OBJECTS[KSEL[wildcards.ksel]["scenario"]].disturbance_dim
    seed = set_seed(int(wildcards.seed), int(wildcards.K), wildcards.sets)
    return disturbance_path(q, wildcards.K, wildcards.method, seed)


def k_selection_points(ks):
    """Every (method, sets, seed, K_i) summary of one k_selection entry (design: first seed)."""
    out = []
    for method in ks["methods"]:
        seeds = ks["seeds"][:1] if method == "design" else ks["seeds"]
        for sets in ks["sets"]:
            for seed in seeds:
                out += [
                    f"results/k_selection/{ks['name']}/{method}_{sets}_seed{seed}/K{K}.json"
                    for K in ks["K_grid"]
                ]
    return out


def nuts_batches(wildcards):
    """The batch tables of a scenario; stops the run, naming the batch to rerun, when a
    record was changed or deleted after its finished batch table was written (a stat per
    record: a damaged record must not go unnoticed until its batch reruns)."""
    from ssmobs.stages import batches, changed_batch_records

    sc = SCENARIO_OBJECTS[wildcards.scenario]
    ranges = batches(sc.K, sc.batch_size(config["stan"]))
    tables = [
        f"results/{wildcards.scenario}/sample_nuts/batch{b}.parquet" for b in range(len(ranges))
    ]
    for table in tables:
        problem = changed_batch_records(table)
        if problem:
            raise WorkflowError(problem)
    return tables


def figure2_disturbances(wildcards=None):
    f2 = config["figure2"]
    return disturbance_path(2, f2["K"], "design", f2["seed"])


def all_targets():
    targets = [f"results/{name}/design_trajectories/trajectories.nc" for name in SCENARIOS]
    targets += [
        f"results/{name}/joint_map/summary.json"
        for name, sc in SCENARIOS.items()
        if sc["joint_map"]
    ]
    targets += [
        f"results/{name}/gather_nuts/summary.json" for name, sc in SCENARIOS.items() if sc["stan"]
    ]
    for name in KSEL:
        targets += expand(f"{OUT}/fig_k_convergence_{name}.{{ext}}", ext=["pdf", "png"])
    if KSEL:
        targets += expand(f"{OUT}/table_k_selection.{{ext}}", ext=["csv", "md", "tex"])
    targets += [exact_summary_path(name) for name in EXACT_SCENARIOS]
    targets += expand(
        f"{OUT}/fig_exact_vs_stan_{{name}}.{{ext}}",
        name=EXACT_VS_STAN_SCENARIOS,
        ext=["pdf", "png"],
    )
    if FIGURE4_SCENARIO:
        targets += expand(
            f"{OUT}/fig4_profile_posterior_{FIGURE4_SCENARIO}.{{ext}}", ext=["pdf", "png"]
        )
    for name in STUDIES:
        targets += expand(f"{OUT}/ours_{name}_observability.{{ext}}", ext=["csv", "md", "png"])
    targets += [f"{OUT}/fig2_design_points.pdf", f"{OUT}/fig2_design_points.png"]
    targets += expand(
        f"{OUT}/{{stem}}.{{ext}}",
        ext=["csv", "md", "tex"],
        stem=["table2_joint_vs_marginal", "table3_coverage", "section4_summary"],
    )
    targets += expand(
        f"{OUT}/{{stem}}.{{ext}}",
        ext=["pdf", "png"],
        stem=["fig3_joint_vs_marginal", "fig_observability_ratios"],
    )
    if MU0_SCENARIOS:
        targets += expand(f"{OUT}/table_mu0_sweep.{{ext}}", ext=["csv", "md", "tex"])
    if STAN_SCENARIOS:
        targets += expand(f"{OUT}/table_convergence_sensitivity.{{ext}}", ext=["csv", "md", "tex"])
    return targets
