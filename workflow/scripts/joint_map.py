"""Rule joint_map: joint MAP and numerical checks of one scenario (Sec. III.B)."""

from ssmobs import log
from ssmobs.stages.joint_map import run_joint_map

log.start_job(snakemake)
run_joint_map(snakemake.params.inputs, dict(snakemake.output.items()))
