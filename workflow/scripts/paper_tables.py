"""Rule paper_tables: Tables II, III and the Section IV summary."""

from ssmobs import io, log
from ssmobs.stages.outputs.paper_tables import run_paper_tables

log.start_job(snakemake)
p, inp, out = snakemake.params.inputs, snakemake.input, snakemake.output
run_paper_tables(
    p.scenario_entries,
    list(p.tables_2_3),
    dict(zip(p.joint_names, inp.joint, strict=True)),
    dict(zip(p.marginal_names, inp.marginal, strict=True)),
    inp.paper_values,
    table2=list(out.table2),
    table3=list(out.table3),
    section4_csv=out.section4_csv,
    section4=list(out.section4),
    exact=dict(zip(p.exact_names, inp.exact, strict=True)),
)
# what made these files (rule of the cache: the stamp holds their key)
io.write_text(snakemake.output.stamp, snakemake.params.key + "\n")
