"""Rule observability_map_cells: every cell of one map, each cached on its own."""

from ssmobs import log
from ssmobs.stages.observability_map import run_map_cells

log.start_job(snakemake)
run_map_cells(snakemake.params.inputs, dict(snakemake.output.items()))
