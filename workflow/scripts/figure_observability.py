"""Rule figure_observability: |K^max|/K and |K^Stan|/K of every scenario."""

from ssmobs import log
from ssmobs.stages import run_figure_observability

log.setup(snakemake.log[0])
run_figure_observability(snakemake.input[0], list(snakemake.output))
