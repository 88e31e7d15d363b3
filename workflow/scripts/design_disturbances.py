"""Rule design_disturbances: one (q x K) disturbance matrix, cached by (q, K, method, seed)."""

from ssmobs import log
from ssmobs.stages.design import run_design_disturbances

log.start_job(snakemake)
wc = snakemake.wildcards
run_design_disturbances(
    int(wc.q), int(wc.K), wc.method, int(wc.seed), snakemake.params.design, snakemake.output[0]
)
