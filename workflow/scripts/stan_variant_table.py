"""Rule stan_variant_table: the variant x row table of Section IV from committed studies."""

from ssmobs import io, log
from ssmobs.stan_variants import CAPTION, read_spec, variant_by_row, variant_rows
from ssmobs.tables import write_table

log.setup(snakemake.log[0])
io.sweep_temporaries(snakemake.output)  # left by an interrupted earlier run
spec = read_spec(snakemake.input.spec)
lines = variant_rows(spec["baselines"], spec["studies"])
write_table(lines, [snakemake.output.csv])
write_table(variant_by_row(lines), [snakemake.output.md], caption=CAPTION)
