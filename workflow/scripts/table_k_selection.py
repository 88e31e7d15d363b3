"""Rule table_k_selection: chosen K per entry, method and seed, and its distribution."""

from ssmobs import io, log
from ssmobs.stages.k_selection.choice import run_table_k_selection

log.start_job(snakemake)
run_table_k_selection(
    list(snakemake.input.selections),
    list(snakemake.output.table),
    list(snakemake.output.distribution),
)
# what made these files (rule of the cache: the stamp holds their key)
io.write_text(snakemake.output.stamp, snakemake.params.key + "\n")
