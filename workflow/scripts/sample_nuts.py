"""Rule sample_nuts: NUTS + checks + marginal MAPs for one batch of trajectories."""

from ssmobs import log
from ssmobs.config.scenario import Scenario
from ssmobs.stages.stan import run_sample_batch

log.start_job(snakemake)
p = snakemake.params
run_sample_batch(
    snakemake.input.trajectories,
    snakemake.input.marker,
    Scenario.from_config(p.scenario),
    p.stan,
    p.convergence,
    int(snakemake.wildcards.batch),
    records_dir=p.records,
    draws_dir=p.draws,
    out=snakemake.output[0],
    threads=snakemake.threads,
    joint_map_theta=snakemake.input.get("joint_map"),
)
