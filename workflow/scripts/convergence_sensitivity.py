"""Rule convergence_sensitivity: |K^Stan| under R-hat 1.01/1.05, tree depth warned/counted;
how the runs that did not converge failed."""

from ssmobs import io, log
from ssmobs.stages.outputs.paper_tables import run_convergence_sensitivity

log.start_job(snakemake)
p = snakemake.params.inputs
run_convergence_sensitivity(
    dict(zip(p.scenario_names, snakemake.input.tables, strict=True)),
    p.convergence_config,
    list(snakemake.output.table),
    list(snakemake.output.failures),
    configs=p.scenario_entries,
)
# what made these files (rule of the cache: the stamp holds their key)
io.write_text(snakemake.output.stamp, snakemake.params.key + "\n")
