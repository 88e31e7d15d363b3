"""Rule figure_profile_posterior: Figure 4."""

from ssmobs import io, log
from ssmobs.config.scenario import Scenario
from ssmobs.stages.outputs.figures import run_figure_profile_posterior

log.start_job(snakemake)
run_figure_profile_posterior(
    snakemake.input[0],
    Scenario.from_config(snakemake.params.scenario),
    snakemake.params.grid,
    list(snakemake.output.figure),
)
# what made these files (rule of the cache: the stamp holds their key)
io.write_text(snakemake.output.stamp, snakemake.params.key + "\n")
