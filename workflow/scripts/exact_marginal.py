"""Rule exact_marginal: exact marginal posteriors of one scenario's design trajectories."""

from ssmobs import log
from ssmobs.stages.exact import run_exact_marginal

log.start_job(snakemake)
run_exact_marginal(snakemake.params.inputs, dict(snakemake.output.items()))
