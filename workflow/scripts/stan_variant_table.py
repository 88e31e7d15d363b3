"""Rule stan_variant_table: the variant x row table of Section IV from committed studies."""

from ssmobs import io, log
from ssmobs.reports.stan_variants import read_spec, write_variant_table

log.start_job(snakemake)
write_variant_table(read_spec(snakemake.input.spec), snakemake.output.csv, snakemake.output.md)
# what made these files (rule of the cache: the stamp holds their key)
io.write_text(snakemake.output.stamp, snakemake.params.key + "\n")
