"""Rule design_trajectories: design states and observations of one scenario."""

from ssmobs import io, log
from ssmobs.scenario import Scenario
from ssmobs.stages.design import run_design_trajectories

log.setup(snakemake.log[0])
io.sweep_temporaries(snakemake.output)  # left by an interrupted earlier run
run_design_trajectories(
    snakemake.input.disturbances,
    Scenario.from_config(snakemake.params.scenario),
    snakemake.output.trajectories,
)
