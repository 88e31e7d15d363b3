"""Rule sample_nuts: NUTS + checks + marginal MAPs for one batch of trajectories."""

from ssmobs import io, log
from ssmobs.scenario import Scenario
from ssmobs.stages.stan import run_sample_batch

log.setup(snakemake.log[0])
io.sweep_temporaries(snakemake.output)  # left by an interrupted earlier run
p = snakemake.params
run_sample_batch(
    snakemake.input.trajectories,
    snakemake.input.marker,
    Scenario.from_config(p.scenario),
    p.stan,
    p.convergence,
    int(snakemake.wildcards.batch),
    p.records,
    p.draws,
    snakemake.output[0],
    threads=snakemake.threads,
    joint_map_theta=snakemake.input.get("joint_map"),
)
