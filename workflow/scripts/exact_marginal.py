"""Rule exact_marginal: exact marginal posteriors of one scenario's design trajectories."""

from ssmobs import log
from ssmobs.config.scenario import Scenario
from ssmobs.stages.exact import run_exact_marginal

log.start_job(snakemake)
run_exact_marginal(
    snakemake.input.trajectories,
    Scenario.from_config(snakemake.params.scenario),
    snakemake.params.settings,
    snakemake.output.table,
    snakemake.output.summary,
)
