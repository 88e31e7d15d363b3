"""Rule figure_profile_posterior: Figure 4."""

from ssmobs import io, log
from ssmobs.config.scenario import Scenario
from ssmobs.stages.outputs.figures import run_figure_profile_posterior

log.start_job(snakemake)
inputs = snakemake.params.inputs
run_figure_profile_posterior(
    snakemake.input.trajectories,
    Scenario.from_config(inputs.scenario_entry),
    inputs.grid_config,
    list(snakemake.output.figure),
)
# what made these files (rule of the cache: the stamp holds their key)
io.write_text(snakemake.output.stamp, snakemake.params.key + "\n")
