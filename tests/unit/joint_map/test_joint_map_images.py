"""The multi-start's images of maxima under the model's found symmetries (issue 60,
ssmobs.joint_map.images), the verdict that counts them, and the labels of its columns:
``starts_per_maximum``, ``symmetric_twin``, ``boundary_higher`` and ``edge_supremum``."""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass

import numpy as np
import pytest
from cubic_sensor_model import CubicSensor
from phase_model import PhaseTracking
from ssmobs.joint_map import images
from ssmobs.joint_map.images import admissible_images, has_distinct_image, symmetry_images
from ssmobs.joint_map.multi_start import maxima_verdict, multi_start_joint_map
from ssmobs.joint_map.multi_start_summary import multi_start_summary
from ssmobs.joint_map.problem import JointMapProblem
from ssmobs.joint_map.settings import JointMapSettings
from ssmobs.models import get_model
from ssmobs.models.symmetries import ModelSymmetries
from two_component_model import TwoComponents

pytestmark = pytest.mark.unit


def trajectories(model, omega, x0, T, K, seed):
    rng = np.random.default_rng(seed)
    q = (model.obs_dim + model.state_dim) * T
    return model.design_trajectories(omega, x0, rng.standard_normal((q, K)), T)[1]


@dataclass(frozen=True)
class FakeMap:
    """A stand-in discrete symmetry: Theta -> scale * Theta + shift on the given columns."""

    columns: tuple[int, ...]
    scale: float = 1.0
    shift: float = 0.0
    infinite_order: bool = False

    def apply(self, model, theta):
        out = np.array(theta, dtype=float)
        out[:, list(self.columns)] = self.scale * out[:, list(self.columns)] + self.shift
        return out

    def apply_inverse(self, model, theta):
        out = np.array(theta, dtype=float)
        out[:, list(self.columns)] = (out[:, list(self.columns)] - self.shift) / self.scale
        return out


@dataclass(frozen=True)
class FakeSymmetries:
    discrete: tuple[FakeMap, ...]

    def images(self, model, theta):
        return ModelSymmetries.images(self, model, theta)  # type: ignore[arg-type]


def test_images_outside_the_support_or_equal_to_the_point_are_not_used(monkeypatch):
    """(Same, a in (0, 1)): a map a -> -a leaves the support; x -> x + 0 is the point
    itself; a shift of the states by 3 is admissible and another point (a twin), and its
    inverse (a translation is used in both directions) too, each once."""
    model = get_model("same")
    T = 4
    z = trajectories(model, [0.9], [8.0], T=T, K=3, seed=1)
    bounds = model.prior_bounds([0.9], "restricted")
    theta = np.column_stack([np.full(3, 0.8), np.ones((3, T + 1))])
    lvar = np.full(theta.shape, 0.01)
    states = tuple(range(1, T + 2))
    fake = FakeSymmetries(
        (
            FakeMap((0,), scale=-1.0),  # a -> -a: outside (0, 1)
            FakeMap(states),  # the identity: the point itself
            FakeMap(states, shift=3.0, infinite_order=True),
            FakeMap(states, shift=3.0),  # the same image again: run once
        )
    )
    monkeypatch.setattr(images, "model_symmetries", lambda m: fake)
    found = admissible_images(model, z, bounds, theta, lvar, 1e-2)
    assert len(found) == len(symmetry_images(model, theta)) == 5
    usable = [mask.tolist() for _, mask in found]
    assert usable == [[False] * 3, [False] * 3, [True] * 3, [True] * 3, [False] * 3]
    np.testing.assert_array_equal(found[2][0][:, 1:], theta[:, 1:] + 3.0)
    np.testing.assert_array_equal(found[3][0][:, 1:], theta[:, 1:] - 3.0)
    assert has_distinct_image(model, z, bounds, theta, lvar, 1e-2).all()
    # without the shift nothing is a twin
    monkeypatch.setattr(images, "model_symmetries", lambda m: FakeSymmetries(fake.discrete[:2]))
    assert not has_distinct_image(model, z, bounds, theta, lvar, 1e-2).any()


def test_a_maximum_with_a_twin_is_never_unique():
    verdict = maxima_verdict(
        np.array([1, 1, 1, 2]), np.array([8, 8, 2, 8]), 8, 0.5, np.array([False, True, True, True])
    )
    assert verdict.tolist() == ["unique", "several", "several", "several"]


def test_two_components_swap_found_without_declaring_it():
    """Issue 60: swapping (a1, x_1) with (a2, x_2) leaves the density unchanged; the model
    declares no mirror_images, the found swap gives the twin of every maximum: no
    trajectory is unique, and every one with a maximum has a twin of the same height."""
    model = TwoComponents()
    assert type(model).mirror_images(model, np.zeros((1, 4))) == []
    omega, x0 = np.array([0.9, 0.3]), np.array([2.0, -1.0])
    z = trajectories(model, omega, x0, T=30, K=8, seed=3)
    settings = JointMapSettings(n_starts=3)
    multi = multi_start_joint_map(
        JointMapProblem(model, z, model.prior_bounds(omega), omega, x0, settings)
    )
    cols = multi.columns()
    found = multi.n_maxima >= 1
    assert found.sum() >= 6
    assert "unique" not in set(cols["maxima_verdict"])
    assert cols["symmetric_twin"][found].all() and not cols["symmetric_twin"][~found].any()
    for k in np.flatnonzero(multi.n_maxima >= 2):
        assert abs(multi.log_post_gap[k]) <= 1e-9 * (1 + abs(multi.maxima_log_post[k][0]))
    # how many of the 3 starts reached each maximum: every passing start in one of them
    assert [int(c.sum()) for c in cols["starts_per_maximum"]] == cols["n_starts_ok"].tolist()
    assert (cols["starts_per_maximum"].map(len) == cols["n_maxima"]).all()
    summary = multi_start_summary(cols, settings)
    assert summary["K_max_unique"] == 0 and summary["K_symmetric_twin"] == int(found.sum())


def test_phase_tracking_translation_twins_and_the_edge_supremum():
    """Issue 60: x -> x + 2 pi (with x0 flat) gives every maximum infinitely many twins,
    so none is unique; the density is highest as b -> inf (mu = 0): starts that run off
    there and still gain are ``edge_supremum``, not ``boundary_higher`` (no start ended
    on the boundary)."""
    model = PhaseTracking()
    omega, x0 = np.array([0.5, 1.0]), np.array([0.0])
    z = trajectories(model, omega, x0, T=20, K=4, seed=0)
    settings = JointMapSettings(n_starts=4)
    multi = multi_start_joint_map(
        JointMapProblem(model, z, model.prior_bounds(omega), omega, x0, settings)
    )
    cols = multi.columns()
    assert "unique" not in set(cols["maxima_verdict"])
    assert cols["symmetric_twin"][multi.n_maxima >= 1].all()
    statuses = Counter(s for r in multi.runs[:4] for s in r.status)
    assert statuses["unbounded"] >= 4 and statuses["boundary"] == 0
    assert cols["edge_supremum"].sum() >= 3 and not cols["boundary_higher"].any()
    for k in np.flatnonzero(cols["edge_supremum"]):
        ran_off = [r for r in multi.runs[:4] if r.status[k] == "unbounded"]
        assert any("b -> +inf" in r.reason[k] for r in ran_off)
        best = -2 * multi.maxima_log_post[k][0] if multi.n_maxima[k] else np.inf
        assert min(r.neg2_log_post[k] for r in ran_off) < best


def test_cubic_sensor_runs_off_to_an_edge_supremum_not_a_boundary():
    """No maximum for any data (b -> +inf on its half-line); every start still gains."""
    model = CubicSensor()
    omega, x0 = np.array([0.5, 0.8]), np.array([1.0])
    z = trajectories(model, omega, x0, T=8, K=4, seed=2)
    bounds = model.prior_bounds(omega, {"b": "half_line"})
    multi = multi_start_joint_map(
        JointMapProblem(model, z, bounds, omega, x0, JointMapSettings(n_starts=3))
    )
    cols = multi.columns()
    assert (cols["n_maxima"] == 0).all()
    assert cols["edge_supremum"].all() and not cols["boundary_higher"].any()
    summary = multi_start_summary(cols, JointMapSettings(n_starts=3))
    assert summary["K_edge_supremum"] == 4 and summary["K_max_unique_edge_supremum"] == 0
