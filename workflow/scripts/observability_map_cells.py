"""Rule observability_map_cells: every cell of one map, each cached on its own."""

from ssmobs import log
from ssmobs.stages.observability_map import run_map_cells

log.start_job(snakemake)
p = snakemake.params
run_map_cells(
    p.entry,
    p.cells,
    p.design_dir,
    p.design,
    p.joint_settings,
    p.exact_settings,
    p.cells_dir,
    snakemake.output[0],
)
