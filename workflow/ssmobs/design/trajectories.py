"""Design trajectories of one scenario (Sec. III.A): x~(k), z~(k), k = 1..K, on disk.

Stored as NetCDF with dims ``k`` (trajectory), ``t`` (1..T), ``state`` (p) and ``obs`` (d);
the scenario's true values, model and provenance are attributes, with a checksum.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass

import numpy as np

from .. import io
from ..config.scenario import Scenario
from ..models import StateSpaceModel, get_model


@dataclass(frozen=True)
class Trajectories:
    """Design states ``x`` (K, T, p) and observations ``z`` (K, T, d) of one scenario."""

    model: StateSpaceModel
    omega: np.ndarray
    x0: np.ndarray
    x: np.ndarray
    z: np.ndarray
    attrs: dict

    @property
    def K(self) -> int:
        return self.x.shape[0]

    @property
    def T(self) -> int:
        return self.x.shape[1]


def make_trajectories(
    scenario: Scenario, matrix: np.ndarray, provenance: dict | None = None
) -> Trajectories:
    """Turn a (q x K) disturbance matrix into the scenario's design trajectories (Sec. III.A)."""
    return trajectories_of(
        scenario.model,
        scenario.omega,
        scenario.x0,
        scenario.T,
        matrix,
        name=scenario.name,
        method=scenario.method,
        seed=scenario.seed,
        provenance=provenance,
    )


def trajectories_of(
    model: StateSpaceModel,
    omega: np.ndarray,
    x0: np.ndarray,
    T: int,
    matrix: np.ndarray,
    *,
    name: str,
    method: str,
    seed: int,
    provenance: dict | None = None,
) -> Trajectories:
    """The design trajectories (Eq. (1)) of ``model`` at true values ``omega``, ``x0`` over
    ``T`` steps from a (q x K) disturbance matrix; ``name``, ``method`` and ``seed`` (the
    scenario's, and its design set's) are written into the attributes."""
    x, z = model.design_trajectories(omega, x0, matrix, T)
    attrs = {
        "scenario": name,
        "model": model.slug,
        "T": T,
        "K": int(matrix.shape[1]),
        "method": method,
        "seed": seed,
        "omega": json.dumps(dict(zip(model.param_names, np.asarray(omega).tolist()))),
        "x0": json.dumps(np.asarray(x0).tolist()),
        # no prior: the trajectories do not depend on it (rule of the cache: a file holds
        # only what its key determines, so a new prior reuses them byte for byte)
    }
    if provenance:
        attrs.update(
            {
                f"disturbances_{k}": v
                for k, v in provenance.items()
                if isinstance(v, (int, float, str))
            }
        )
    return Trajectories(model=model, omega=np.array(omega), x0=np.array(x0), x=x, z=z, attrs=attrs)


def write_trajectories(path: str | os.PathLike, traj: Trajectories) -> None:
    K, T, p = traj.x.shape
    d = traj.z.shape[2]
    io.write_netcdf(
        path,
        {
            "k": (("k",), np.arange(K)),
            "t": (("t",), np.arange(1, T + 1)),
            "state": (("state",), np.arange(p)),
            "obs": (("obs",), np.arange(d)),
            "x": (("k", "t", "state"), traj.x),
            "z": (("k", "t", "obs"), traj.z),
        },
        {**traj.attrs, "checksum": io.array_checksum(traj.x, traj.z)},
    )


def read_trajectories(path: str | os.PathLike) -> Trajectories:
    """Load and validate a trajectories file (CorruptFileError naming the file if damaged)."""
    ds = io.read_netcdf(path, required_vars=["x", "z"])
    x = np.asarray(ds["x"], dtype=float)
    z = np.asarray(ds["z"], dtype=float)
    attrs = dict(ds.attrs)
    if attrs.get("checksum") != io.array_checksum(x, z):
        raise io.CorruptFileError(f"{path}: checksum mismatch (file damaged or edited)")
    model = get_model(attrs["model"])
    omega = np.array(list(json.loads(attrs["omega"]).values()), dtype=float)
    x0 = np.array(json.loads(attrs["x0"]), dtype=float)
    return Trajectories(model=model, omega=omega, x0=x0, x=x, z=z, attrs=attrs)
