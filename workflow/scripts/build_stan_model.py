"""Rule build_stan_model: compile one Stan program once."""

from ssmobs import io, log
from ssmobs.stages.stan import run_build_stan_model

log.setup(snakemake.log[0])
io.sweep_temporaries(snakemake.output)  # left by an interrupted earlier run
run_build_stan_model(snakemake.wildcards.model, snakemake.params.backend, snakemake.output[0])
