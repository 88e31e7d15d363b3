"""Rule observability_map: one map's table and figure from the table of its cells."""

from ssmobs import io, log
from ssmobs.stages.observability_map import write_map

log.start_job(snakemake)
out = snakemake.output
write_map(
    snakemake.input.cells,
    snakemake.params.inputs.map_entry,
    {"csv": out.csv, "md": out.md, "png": out.png, "pdf": out.pdf},
)
# what made these files (rule of the cache: the stamp holds their key)
io.write_text(out.stamp, snakemake.params.key + "\n")
