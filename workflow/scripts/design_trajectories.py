"""Rule design_trajectories: design states and observations of one scenario."""

from ssmobs import log
from ssmobs.stages.design import run_design_trajectories

log.start_job(snakemake)
run_design_trajectories(snakemake.params.inputs, dict(snakemake.output.items()))
