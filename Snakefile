# ssmobs: observability of nonlinear Gaussian state space models (Hanebeck & Czado).
#
# Output scheme
#   results/shared/...        artefacts shared by scenarios, keyed by exactly what they depend on
#     design_disturbances/q{q}_K{K}_{method}_seed{seed}.nc   (q = (d+p)T)
#   results/{scenario}/...    one folder per rule for each configured scenario
#     design_trajectories/trajectories.nc
#   results/k_selection/{name}/...   runs of the choice of K (Sec. IV.A)
#   results/{scenario}/logs, results/shared/logs    one log per job
#   paper_figures/            final tables and figures (see paper_figures/README.md)
#
# Default config: config/config.yaml; others with --configfile config/smoke.yaml|paper.yaml.

from snakemake.utils import min_version

min_version("9.0")


# config/config.yaml is the default; a profile given with --configfile replaces it whole
# (Snakemake would otherwise deep-merge the two and leak default settings into it).
if not workflow.overwrite_configfiles:

    configfile: "config/config.yaml"


include: "workflow/rules/common.smk"
include: "workflow/rules/design.smk"
include: "workflow/rules/joint_map.smk"
include: "workflow/rules/stan.smk"
include: "workflow/rules/figures.smk"
include: "workflow/rules/outputs.smk"
include: "workflow/rules/own_model.smk"


rule all:
    """Every output of the configured scenarios and the paper figures."""
    input:
        all_targets(),
    default_target: True
