"""Rule observability_study: one model's |K^max|/K and |K^Stan|/K over T."""

from ssmobs import log
from ssmobs.scenario import Scenario
from ssmobs.observability_study import run_observability_study

log.setup(snakemake.log[0])
run_observability_study(snakemake.params.study,
                        [Scenario.from_config(sc) for sc in snakemake.params.scenarios],
                        snakemake.params.joint, snakemake.params.stan,
                        snakemake.params.stan_tables, snakemake.output.csv, snakemake.output.md,
                        snakemake.output.png, stan_settings=snakemake.params.stan_settings)
