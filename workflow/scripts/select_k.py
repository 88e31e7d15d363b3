"""Rule select_k: the choice of K by relative differences (Sec. IV.A)."""

from ssmobs import io, log
from ssmobs.config.scenario import Scenario
from ssmobs.stages.k_selection.choice import run_select_k

log.start_job(snakemake)
p, out = snakemake.params.inputs, snakemake.output
run_select_k(
    p.ksel_entry,
    Scenario.from_config(p.scenario_entry),
    list(snakemake.input.grids),
    snakemake.input.paper_values,
    out.json,
    out.csv,
    list(out.figure),
)
# what made these files (rule of the cache: the stamp holds their key)
io.write_text(snakemake.output.stamp, snakemake.params.key + "\n")
