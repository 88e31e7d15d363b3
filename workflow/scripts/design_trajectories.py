"""Rule design_trajectories: design states and observations of one scenario."""

from ssmobs import io, log
from ssmobs.scenario import Scenario
from ssmobs.trajectories import make_trajectories, write_trajectories

logger = log.setup(snakemake.log[0])
io.sweep_temporaries(snakemake.output)  # left by an interrupted earlier run
sc = Scenario.from_config(snakemake.params.scenario)
matrix, attrs = io.read_disturbances(snakemake.input.disturbances, q=sc.disturbance_dim, K=sc.K)
traj = make_trajectories(sc, matrix, provenance=attrs)
logger.info("scenario %s: %d trajectories of length %d", sc.name, traj.K, traj.T)
write_trajectories(snakemake.output.trajectories, traj)
io.write_checksum(snakemake.output.trajectories)
