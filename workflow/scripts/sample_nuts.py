"""Rule sample_nuts: NUTS + checks + marginal MAPs for one batch of trajectories."""

from ssmobs import log
from ssmobs.stages.stan import run_sample_batch

log.start_job(snakemake)
run_sample_batch(snakemake.params.inputs, dict(snakemake.output.items()))
