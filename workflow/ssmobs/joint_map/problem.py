"""One joint-MAP problem (Sec. III.B): what the driver (:mod:`ssmobs.joint_map.driver`),
the multi-start (:mod:`ssmobs.joint_map.multi_start`) and the image runs
(:mod:`ssmobs.joint_map.images`) all optimise.

:class:`JointMapProblem` holds the six things every joint MAP of a set of design
trajectories needs: the model, the observations z~(k), the prior support of Omega
(Eq. (3)), the true values (the paper's start) and the settings.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from ..models.base import PriorBounds, StateSpaceModel
from .settings import JointMapSettings


class TrajectoriesLike(Protocol):
    """What a problem is built from: a scenario's design trajectories (the design stage's
    :class:`~ssmobs.design.trajectories.Trajectories`)."""

    @property
    def model(self) -> StateSpaceModel: ...
    @property
    def z(self) -> np.ndarray: ...
    @property
    def omega(self) -> np.ndarray: ...
    @property
    def x0(self) -> np.ndarray: ...


@dataclass(frozen=True, eq=False)
class JointMapProblem:
    """The joint MAP of every trajectory of ``z`` (K, T, d) under the flat prior on
    ``bounds``, started at the true values (``omega_true``, ``x0_true``) with ``settings``."""

    model: StateSpaceModel
    z: np.ndarray
    bounds: PriorBounds
    omega_true: np.ndarray
    x0_true: np.ndarray
    settings: JointMapSettings = field(default_factory=JointMapSettings)

    @classmethod
    def of_trajectories(
        cls, traj: TrajectoriesLike, prior: Any, settings: Mapping[str, Any]
    ) -> JointMapProblem:
        """The problem of a scenario's design trajectories under its prior (variants or an
        interval per parameter, :meth:`StateSpaceModel.prior_bounds`) and its merged
        ``joint_map`` block."""
        return cls(
            traj.model,
            traj.z,
            traj.model.prior_bounds(traj.omega, prior),
            traj.omega,
            traj.x0,
            JointMapSettings.from_mapping(settings),
        )

    @property
    def T(self) -> int:
        """The trajectories' length."""
        return int(np.shape(self.z)[1])

    def replace(self, **changes: Any) -> JointMapProblem:
        """This problem with some fields changed (a start, a subset of rows, settings)."""
        return dataclasses.replace(self, **changes)
