"""Rule paper_tables: Tables II, III and the Section IV summary."""

from pathlib import Path

from ssmobs import io, log
from ssmobs.stages import run_paper_tables

log.setup(snakemake.log[0])
io.sweep_temporaries(snakemake.output)  # left by an interrupted earlier run
p = snakemake.params
run_paper_tables(p.scenarios, p.joint, p.marginal, snakemake.input.paper_values,
                 Path(snakemake.output[0]).parent, exact=p.exact)
