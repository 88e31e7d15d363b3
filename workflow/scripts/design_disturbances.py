"""Rule design_disturbances: one (q x K) disturbance matrix, cached by (q, K, method, seed)."""

from ssmobs import io, log
from ssmobs.design_disturbances import design_disturbances

logger = log.setup(snakemake.log[0])
io.sweep_temporaries(snakemake.output)  # left by an interrupted earlier run
wc = snakemake.wildcards
q, K, seed = int(wc.q), int(wc.K), int(wc.seed)
logger.info("design disturbances q=%d K=%d method=%s seed=%d", q, K, wc.method, seed)
result = design_disturbances(
    q, K, wc.method, seed, b_max=snakemake.params.design["b_max"], progress=logger.info
)
logger.info(
    "done: %d iterations, distance %.6g (before covariance correction %.6g), %s",
    result.iterations,
    result.distance,
    result.distance_raw,
    result.covariance_correction,
)
io.write_disturbances(snakemake.output[0], result)
