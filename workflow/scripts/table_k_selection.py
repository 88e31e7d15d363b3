"""Rule table_k_selection: chosen K per entry, method and seed."""

from pathlib import Path

from ssmobs import log
from ssmobs.stages import run_table_k_selection

log.setup(snakemake.log[0])
run_table_k_selection(list(snakemake.input), Path(snakemake.output[0]).with_suffix(""))
