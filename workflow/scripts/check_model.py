"""Rules check_model and check_model_stan: the model alone, or against its Stan program."""

from ssmobs import log
from ssmobs.model_check.check import run_check_model

logger = log.start_job(snakemake)
inputs = snakemake.params.inputs  # what the check's key is made of (ModelCheckInputs)
paths = {
    "report": snakemake.output[0],
    # no file for a model without stan/<model>.stan: its program is generated
    "stan": snakemake.input.get("stan") or None,
    # with the native backend, build_stan_model's marker: the check runs the program it wrote
    "program": next(iter(snakemake.input.get("program", [])), None),
}
report = run_check_model(inputs, paths)
for line in report.checks:
    logger.info("model %s: checked %s", inputs.model, line)
