"""Rule k_selection_point: V_{K_i} of the choice of K for one K_i (Sec. IV.A)."""

from ssmobs import io, log
from ssmobs.scenario import Scenario
from ssmobs.stages import run_k_selection_point

log.setup(snakemake.log[0])
io.sweep_temporaries(snakemake.output)  # left by an interrupted earlier run
wc = snakemake.wildcards
run_k_selection_point(
    snakemake.input[0],
    Scenario.from_config(snakemake.params.scenario),
    int(wc.K),
    wc.method,
    int(wc.seed),
    snakemake.params.settings,
    snakemake.output[0],
    sets=wc.sets,
)
