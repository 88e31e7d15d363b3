"""Rule design_trajectories: design states and observations of one scenario."""

from ssmobs import log
from ssmobs.config.scenario import Scenario
from ssmobs.stages.design import run_design_trajectories

log.start_job(snakemake)
run_design_trajectories(
    snakemake.input.disturbances,
    Scenario.from_config(snakemake.params.scenario),
    snakemake.output.trajectories,
)
