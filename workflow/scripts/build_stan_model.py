"""Rule build_stan_model: compile one Stan program once."""

from ssmobs import log
from ssmobs.stages.stan import run_build_stan_model

log.start_job(snakemake)
run_build_stan_model(
    snakemake.wildcards.model,
    snakemake.params.backend,
    snakemake.output[0],
    snakemake.params.gradients,
)
