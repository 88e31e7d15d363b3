"""Rule gather_nuts: the Stan stage's summary of one scenario."""

from ssmobs import log
from ssmobs.stages.stan import run_gather_nuts

log.start_job(snakemake)
run_gather_nuts(snakemake.params.inputs, dict(snakemake.output.items()))
