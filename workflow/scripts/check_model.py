"""Rules check_model and check_model_stan: the model alone, or against its Stan program."""

from ssmobs import log
from ssmobs.model_check.check import run_check_model

logger = log.start_job(snakemake)
inputs = snakemake.params.inputs  # what the check's key is made of (CacheKeys.check_inputs)
report = run_check_model(
    inputs["model"],
    inputs["scenarios"],
    snakemake.output[0],
    stan=inputs["stan"],
    # no file for a model without stan/<model>.stan: the check generates its program
    stan_path=(snakemake.input.get("stan") or None) if inputs["stan"] else None,
    gradients=inputs["gradients"],
)
for line in report.checks:
    logger.info("model %s: checked %s", inputs["model"], line)
