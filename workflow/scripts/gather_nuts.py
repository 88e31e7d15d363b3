"""Rule gather_nuts: the Stan stage's summary of one scenario."""

from ssmobs import log
from ssmobs.config.scenario import Scenario
from ssmobs.stages.stan import run_gather_nuts

log.start_job(snakemake)
run_gather_nuts(
    snakemake.input.trajectories,
    list(snakemake.input.batches),
    Scenario.from_config(snakemake.params.scenario),
    snakemake.params.convergence,
    snakemake.params.records,
    snakemake.output.table,
    snakemake.output.summary,
)
