"""Rule figure_observability: |K^max|/K and |K^Stan|/K of every scenario."""

from ssmobs import io, log
from ssmobs.stages.outputs.figures import run_figure_observability

log.start_job(snakemake)
run_figure_observability(snakemake.input.summary, list(snakemake.output.figure))
# what made these files (rule of the cache: the stamp holds their key)
io.write_text(snakemake.output.stamp, snakemake.params.key + "\n")
