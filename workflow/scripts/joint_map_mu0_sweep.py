"""Rule joint_map_mu0_sweep: |K^max|/K of the Sep models over a range of barrier starts."""

from ssmobs import io, log
from ssmobs.config.scenario import Scenario
from ssmobs.stages.outputs.mu0_sweep import run_joint_map_mu0_sweep

log.start_job(snakemake)
p = snakemake.params.inputs
entries = p.scenario_entries
names = [sc["name"] for sc in entries]
run_joint_map_mu0_sweep(
    dict(zip(names, snakemake.input.trajectories, strict=True)),
    {sc["name"]: Scenario.from_config(sc) for sc in entries},
    p.settings_config,
    list(p.mu0_per_T),
    snakemake.input.paper_values,
    list(snakemake.output.table),
)
# what made these files (rule of the cache: the stamp holds their key)
io.write_text(snakemake.output.stamp, snakemake.params.key + "\n")
