"""Rule figure_design_points: Figure 2 of the paper."""

from ssmobs import io, log
from ssmobs.reports.figures import figure_design_points

logger = log.start_job(snakemake)
f2 = snakemake.params.inputs.figure_config
matrix, _ = io.read_disturbances(snakemake.input.disturbances, q=2, K=f2["K"])
figure_design_points(matrix, f2["a"], f2["x0"], [snakemake.output.pdf, snakemake.output.png])
logger.info("wrote %s and %s", snakemake.output.pdf, snakemake.output.png)
# what made these files (rule of the cache: the stamp holds their key)
io.write_text(snakemake.output.stamp, snakemake.params.key + "\n")
