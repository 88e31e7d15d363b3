"""Rule observability_map: one map's cells (each cached on its own), table and figure."""

from ssmobs import io, log
from ssmobs.observability_map import run_observability_map

log.setup(snakemake.log[0])
out, p = snakemake.output, snakemake.params
io.sweep_temporaries(out)  # left by an interrupted earlier run
run_observability_map(
    p.entry,
    p.cells,
    p.design_dir,
    p.design,
    p.joint_settings,
    p.exact_settings,
    p.cells_dir,
    {"csv": out.csv, "md": out.md, "png": out.png, "pdf": out.pdf},
)
# what made these files (rule of the cache: the stamp holds their key)
io.write_text(out.stamp, p.key + "\n")
