"""Rule design_disturbances: one (q x K) disturbance matrix, cached by (q, K, method, seed)."""

from ssmobs import io, log
from ssmobs.stages.design import run_design_disturbances

log.setup(snakemake.log[0])
io.sweep_temporaries(snakemake.output)  # left by an interrupted earlier run
wc = snakemake.wildcards
run_design_disturbances(
    int(wc.q), int(wc.K), wc.method, int(wc.seed), snakemake.params.design, snakemake.output[0]
)
