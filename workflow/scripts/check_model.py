"""Rule check_model: the model's Python module against its Stan program."""

from ssmobs import log
from ssmobs.check_model import run_check_model

logger = log.setup(snakemake.log[0])
report = run_check_model(
    snakemake.wildcards.model,
    snakemake.params.scenarios,
    snakemake.output[0],
    stan=snakemake.params.stan,
    stan_path=snakemake.input.stan,
)
for line in report.checks:
    logger.info("model %s: checked %s", snakemake.wildcards.model, line)
