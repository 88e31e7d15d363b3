"""Rule convergence_sensitivity: |K^Stan| under R-hat 1.01/1.05, tree depth warned/counted."""

from pathlib import Path

from ssmobs import log
from ssmobs.stages import run_convergence_sensitivity

log.setup(snakemake.log[0])
run_convergence_sensitivity(dict(snakemake.params.tables), snakemake.params.convergence,
                            Path(snakemake.output[0]).with_suffix(""))
