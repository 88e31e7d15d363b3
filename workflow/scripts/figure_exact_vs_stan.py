"""Rule figure_exact_vs_stan: Stan + KDE marginal MAP against the exact one."""

from ssmobs import io, log
from ssmobs.config.scenario import Scenario
from ssmobs.stages.outputs.figures import run_figure_exact_vs_stan

logger = log.start_job(snakemake)
table = run_figure_exact_vs_stan(
    Scenario.from_config(snakemake.params.inputs.scenario_entry),
    snakemake.input.stan,
    snakemake.input.exact,
    list(snakemake.output.figure),
    list(snakemake.output.table),
)
logger.info("Stan + KDE vs exact:\n%s", table.to_string(index=False))
# what made these files (rule of the cache: the stamp holds their key)
io.write_text(snakemake.output.stamp, snakemake.params.key + "\n")
