"""Rules check_model and check_model_stan: the model alone, or against its Stan program."""

from ssmobs import log
from ssmobs.model_check.check import run_check_model

logger = log.start_job(snakemake)
report = run_check_model(
    snakemake.params.model,
    snakemake.params.scenarios,
    snakemake.output[0],
    stan=snakemake.params.stan,
    # no file for a model without stan/<model>.stan: the check generates its program
    stan_path=(snakemake.input.get("stan") or None) if snakemake.params.stan else None,
    gradients=snakemake.config["stan"]["gradients"] if snakemake.params.stan else "autodiff",
)
for line in report.checks:
    logger.info("model %s: checked %s", snakemake.params.model, line)
