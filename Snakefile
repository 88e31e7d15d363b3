# ssmobs: observability of nonlinear Gaussian state space models (Hanebeck & Czado).
#
# Output scheme: every cached output lives under a key of everything that determines it
# (config values, inputs' keys, code: ssmobs/cache_keys.py), with its log beside it
#   results/shared/design_disturbances/<key>/q{q}_K{K}_{method}_seed{seed}.nc  (q = (d+p)T)
#   results/{scenario}/<stage>/<key>/...     one folder per stage and key of each scenario
#   results/k_selection/{name}/<key>/...     grids of the choice of K (Sec. IV.A)
#   results/shared/k_selection_points/<key>/...  its points V_{K_i}, shared by its entries
#   results/observability_map/cells/<key>.json  one cell of an observability map
#   results/outputs/<outputs_dir>/*.key      what made each table and figure (stamps)
#   <outputs_dir>/            final tables and figures (see paper_figures/README.md)
#
# Default config: config/config.yaml; others with --configfile config/smoke.yaml|paper.yaml.

import sys
from pathlib import Path

from snakemake.utils import min_version

min_version("9.0")

sys.path.insert(0, str(Path(workflow.basedir) / "workflow"))

from ssmobs import kernels  # noqa: E402

# Every job computes with the same kernels whatever this CPU (OpenBLAS's Haswell kernels, NumPy
# up to AVX2, one thread): set here, before any job starts, and inherited by every job, local
# or on SLURM (whose job-side Snakemake reads this file again); each job checks (issue 34).
kernels.apply()


# config/config.yaml is the default; a profile given with --configfile replaces it whole
# (Snakemake would otherwise deep-merge the two and leak default settings into it).
if not workflow.overwrite_configfiles:
    from ssmobs.config.validation import ConfigError
    from ssmobs.config.preflight import load_config_file

    try:  # our reading first: one line naming the file (and line, column) when it is bad
        load_config_file("config/config.yaml")
    except ConfigError as err:
        raise WorkflowError(str(err)) from None

    configfile: "config/config.yaml"


include: "workflow/rules/common.smk"
include: "workflow/rules/design.smk"
include: "workflow/rules/joint_map.smk"
include: "workflow/rules/k_selection.smk"
include: "workflow/rules/stan.smk"
include: "workflow/rules/exact_marginal.smk"
include: "workflow/rules/outputs.smk"
include: "workflow/rules/figures.smk"
include: "workflow/rules/own_model.smk"
include: "workflow/rules/observability_map.smk"
include: "workflow/rules/stan_variants.smk"


stop_without_compiler()
# stale stamps and damaged files are removed before the DAG is built, all or none
remove_stale(repairs_before_the_dag())


onstart:
    stop_where_jobs_cannot_write()


onsuccess:
    set_aside_leftovers()


rule all:
    """Every output of the configured scenarios and the paper figures."""
    default_target: True
    input:
        PATHS.targets(STAMPS, DAMAGED_TARGETS),
