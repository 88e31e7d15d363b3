"""Rule joint_map: joint MAP and numerical checks of one scenario (Sec. III.B)."""

from ssmobs import log
from ssmobs.config.scenario import Scenario
from ssmobs.stages.joint_map import run_joint_map

log.start_job(snakemake)
run_joint_map(
    snakemake.input[0],
    Scenario.from_config(snakemake.params.scenario),
    snakemake.params.settings,
    table=snakemake.output.table,
    summary=snakemake.output.summary,
    theta=snakemake.output.theta,
)
