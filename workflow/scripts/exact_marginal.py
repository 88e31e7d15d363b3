"""Rule exact_marginal: exact marginal posteriors of one scenario's design trajectories."""

from ssmobs import io, log
from ssmobs.scenario import Scenario
from ssmobs.stages.exact import run_exact_marginal

log.setup(snakemake.log[0])
io.sweep_temporaries(snakemake.output)  # left by an interrupted earlier run
run_exact_marginal(
    snakemake.input.trajectories,
    Scenario.from_config(snakemake.params.scenario),
    snakemake.params.settings,
    snakemake.output.table,
    snakemake.output.summary,
)
