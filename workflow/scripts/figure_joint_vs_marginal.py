"""Rule figure_joint_vs_marginal: Figure 3."""

from ssmobs import io, log
from ssmobs.stages.outputs.figures import run_figure_joint_vs_marginal

log.start_job(snakemake)
scenarios = snakemake.params.inputs.scenario_entries
names = [sc["name"] for sc in scenarios]
run_figure_joint_vs_marginal(
    scenarios,
    dict(zip(names, snakemake.input.joint, strict=True)),
    dict(zip(names, snakemake.input.marginal, strict=True)),
    list(snakemake.output.figure),
)
# what made these files (rule of the cache: the stamp holds their key)
io.write_text(snakemake.output.stamp, snakemake.params.key + "\n")
