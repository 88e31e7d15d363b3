"""Rule observability_study: one model's |K^max|/K and |K^Stan|/K over T."""

from ssmobs import io, log
from ssmobs.config.scenario import Scenario
from ssmobs.reports.observability_study import run_observability_study

log.start_job(snakemake)
p, inp = snakemake.params.inputs, snakemake.input
run_observability_study(
    p.study_entry,
    [Scenario.from_config(sc) for sc in p.scenario_entries],
    dict(zip(p.joint_names, inp.joint, strict=True)),
    dict(zip(p.stan_names, inp.stan, strict=True)),
    dict(zip(p.stan_names, inp.stan_tables, strict=True)),
    snakemake.output.csv,
    snakemake.output.md,
    snakemake.output.png,
    stan_settings=p.stan_config,
)
# what made these files (rule of the cache: the stamp holds their key)
io.write_text(snakemake.output.stamp, snakemake.params.key + "\n")
