"""Rule k_selection_grid: V_{K_i} of the choice of K for every K_i of one grid (Sec. IV.A)."""

from ssmobs import log
from ssmobs.stages.k_selection.grid import run_k_selection_grid

log.start_job(snakemake)
run_k_selection_grid(snakemake.params.inputs, dict(snakemake.output.items()))
