"""Rule joint_map_mu0_sweep: |K^max|/K of the Sep models over a range of barrier starts."""

from pathlib import Path

from ssmobs import log
from ssmobs.scenario import Scenario
from ssmobs.stages import run_joint_map_mu0_sweep

log.setup(snakemake.log[0])
p = snakemake.params
run_joint_map_mu0_sweep(dict(p.trajectories),
                        {n: Scenario.from_config(sc) for n, sc in p.scenarios.items()},
                        dict(p.settings),
                        list(p.mu0_per_T), snakemake.input.paper_values,
                        Path(snakemake.output[0]).with_suffix(""))
