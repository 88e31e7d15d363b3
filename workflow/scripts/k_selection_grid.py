"""Rule k_selection_grid: V_{K_i} of the choice of K for every K_i of one grid (Sec. IV.A)."""

from ssmobs import log
from ssmobs.config.scenario import Scenario
from ssmobs.stages.k_selection.grid import run_k_selection_grid

log.start_job(snakemake)
wc, p = snakemake.wildcards, snakemake.params
run_k_selection_grid(
    p.design_dir,
    Scenario.from_config(p.scenario),
    list(p.K_grid),
    wc.method,
    int(wc.seed),
    wc.sets,
    dict(p.settings),
    dict(p.design),
    points_dir=p.points,
    out=snakemake.output[0],
)
