"""Rule figure_joint_vs_marginal: Figure 3."""

from ssmobs import io, log
from ssmobs.stages import run_figure_joint_vs_marginal

log.setup(snakemake.log[0])
io.sweep_temporaries(snakemake.output)  # left by an interrupted earlier run
p = snakemake.params
run_figure_joint_vs_marginal(p.scenarios, p.joint, p.marginal, list(snakemake.output))
