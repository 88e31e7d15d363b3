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
    # no file for a model without stan/<model>.stan: its program is generated
    stan_path=(snakemake.input.get("stan") or None) if inputs["stan"] else None,
    gradients=inputs["gradients"],
    # with the native backend, build_stan_model's marker: the check runs the program it wrote
    program_marker=next(iter(snakemake.input.get("program", [])), None),
)
for line in report.checks:
    logger.info("model %s: checked %s", inputs["model"], line)
