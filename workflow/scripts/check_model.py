"""Rules check_model and check_model_stan: the model alone, or against its Stan program."""

from ssmobs import io, log
from ssmobs.check_model import run_check_model

logger = log.setup(snakemake.log[0])
io.sweep_temporaries(snakemake.output)  # left by an interrupted earlier run
report = run_check_model(
    snakemake.params.model,
    snakemake.params.scenarios,
    snakemake.output[0],
    stan=snakemake.params.stan,
    stan_path=snakemake.input.stan if snakemake.params.stan else None,
)
for line in report.checks:
    logger.info("model %s: checked %s", snakemake.params.model, line)
