"""Multi-start joint MAP (ssmobs.joint_map.multi_start; issue 36): starts, distinct maxima,
K^max_unique.

On the growth test model (tests/growth_model.py), whose every maximum has a mirror image of
the same height, one start per trajectory overstates how many trajectories have a unique
maximum.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from factories import same_a09
from growth_model import Growth
from ssmobs.config.scenario import Scenario
from ssmobs.joint_map.driver import JointMapResult, joint_map
from ssmobs.joint_map.multi_start import (
    distinct_maxima,
    halton,
    multi_start_joint_map,
    start_box,
    start_points,
)
from ssmobs.joint_map.multi_start_summary import multi_start_summary
from ssmobs.joint_map.problem import JointMapProblem
from ssmobs.joint_map.settings import JointMapSettings
from ssmobs.models import get_model
from ssmobs.reports.tables import section_iv, section_iv_compact

pytestmark = pytest.mark.unit


def trajectories(model, omega, x0, T, K, seed):
    rng = np.random.default_rng(seed)
    q = (model.obs_dim + model.state_dim) * T
    return model.design_trajectories(omega, x0, rng.standard_normal((q, K)), T)[1]


# --------------------------------------------------------------------------- starts
def test_halton_points_are_the_radical_inverses_inside_the_cube():
    pts = halton(4, 2)
    assert np.allclose(pts[:, 0], [1 / 2, 1 / 4, 3 / 4, 1 / 8])
    assert np.allclose(pts[:, 1], [1 / 3, 2 / 3, 1 / 9, 4 / 9])
    many = halton(500, 5)
    assert np.all((many > 0) & (many < 1))
    assert len(np.unique(many, axis=0)) == 500


def test_start_box_and_points_respect_prior_and_constraints():
    model = get_model("sep_d1_p2")  # 1 - a^2 - b^2 > 0 besides the box (0, 1)^4
    omega, x0 = np.array([0.6, 0.5, 0.9, 0.9]), np.array([8.0, 8.0])
    bounds = model.prior_bounds(omega, "restricted")
    lo, hi = start_box(bounds, omega, x0, span=3.0)
    assert np.allclose(lo, [0, 0, 0, 0, -16, -16]) and np.allclose(hi, [1, 1, 1, 1, 32, 32])
    pts = start_points(model, bounds, omega, x0, 12, 3.0)
    assert pts.shape == (12, 6)
    assert np.array_equal(pts[0], [0.6, 0.5, 0.9, 0.9, 8.0, 8.0])  # the paper's start first
    inside = (pts[1:, :4] > 0) & (pts[1:, :4] < 1)
    assert inside.all() and np.all(pts[1:, 0] ** 2 + pts[1:, 1] ** 2 < 1)
    # the Halton points that break the constraint were skipped, not moved
    raw = lo + halton(11, 6) * (hi - lo)
    assert np.any(raw[:, 0] ** 2 + raw[:, 1] ** 2 >= 1)
    assert len(np.unique(pts, axis=0)) == 12
    # a side without a finite bound: span * max(1, |true|) from the true value
    mult = get_model("sep_mult")
    lo, hi = start_box(mult.prior_bounds([0.9], "half_line"), np.array([0.9]), x0, 3.0)
    assert np.allclose([lo[0], hi[0]], [0.0, 3.9])


def test_settings_are_checked():
    with pytest.raises(ValueError, match="n_starts"):
        JointMapSettings(n_starts=0)
    with pytest.raises(ValueError, match="distinct_tol"):
        JointMapSettings(distinct_tol=0.0)
    assert JointMapSettings().n_starts == 1  # the paper's single start by default


# --------------------------------------------------------------------------- distinct maxima
def fake_run(theta, f, status, lvar=1.0):
    theta = np.atleast_2d(np.asarray(theta, dtype=float))
    K, n = theta.shape
    return JointMapResult(
        theta_hat=theta,
        neg2_log_post=np.asarray(f, dtype=float),
        local_variance=np.full((K, n), lvar),
        eig_ratio=np.ones(K),
        grad_max=np.zeros(K),
        iterations=np.ones(K, dtype=np.int64),
        status=np.asarray(status, dtype=object),
        reason=np.full(K, "", dtype=object),
    )


def test_clustering_uses_the_tolerance_in_local_standard_deviations():
    settings = JointMapSettings(distinct_tol=1e-2)
    runs = [
        fake_run([[1.0, 2.0]], [10.0], ["ok"], lvar=4.0),  # sd 2
        fake_run([[1.0 + 0.019, 2.0]], [10.0 + 1e-12], ["ok"], lvar=4.0),  # 0.0095 sd: same
        fake_run([[1.0 - 0.021, 2.0]], [9.0], ["ok"], lvar=4.0),  # 0.0105 sd: another
        fake_run([[5.0, 5.0]], [1.0], ["gradient"]),  # fails a check: no maximum
    ]
    values, first, paper_highest = distinct_maxima(runs, 0, settings)
    assert values.tolist() == [9.0, 10.0]  # -2 pi, highest posterior first
    assert first.tolist() == [2, 0]
    assert not paper_highest
    ms = multi_start_summary(
        pd.DataFrame(
            {
                "n_maxima": [2, 1, 0, 1],
                "maxima_verdict": ["several", "unique", "none", "unique"],
                "log_post_gap": [0.5, np.nan, np.nan, np.nan],
                "paper_start_highest": [False, True, False, True],
                "boundary_higher": [False, True, False, False],
            }
        ),
        settings,
    )
    assert (ms["K_max_unique"], ms["K_max_any"], ms["K_max_several"]) == (2, 3, 1)
    assert ms["K_paper_start_highest"] == 2 and ms["log_post_gap_median"] == 0.5
    assert ms["K_max_unique_boundary_higher"] == 1
    assert 0 < ms["K_max_unique_lo95"] < 0.5 < ms["K_max_unique_hi95"] < 1


def test_an_exact_tie_counts_as_the_paper_start_reaching_the_highest():
    runs = [
        fake_run([[1.0, 2.0]], [10.0], ["ok"]),
        fake_run([[-1.0, -2.0]], [10.0 - 1e-13], ["ok"]),  # a mirror image, same height
    ]
    values, _, paper_highest = distinct_maxima(runs, 0, JointMapSettings())
    assert values.size == 2 and paper_highest


# --------------------------------------------------------------------------- the optimiser
@pytest.fixture(scope="module")
def same_case():
    model = get_model("same")
    z = trajectories(model, [0.9], [8.0], T=10, K=10, seed=4)
    return model, z, model.prior_bounds([0.9], "restricted")


def test_one_start_is_the_paper_joint_map_exactly(same_case):
    model, z, bounds = same_case
    single = joint_map(JointMapProblem(model, z, bounds, [0.9], [8.0]))
    multi = multi_start_joint_map(
        JointMapProblem(model, z, bounds, np.array([0.9]), np.array([8.0]), JointMapSettings())
    )
    assert len(multi.runs) == 1
    for field in dataclasses.fields(JointMapResult):
        a, b = getattr(single, field.name), getattr(multi.runs[0], field.name)
        np.testing.assert_array_equal(a, b, err_msg=field.name, strict=True)  # NaN == NaN
    assert np.array_equal(multi.n_maxima, single.ok.astype(int))


def test_same_has_one_maximum_per_trajectory_from_every_start(same_case):
    """(Same, a = 0.9, T = 10): the starts that pass all reach the paper's maximum."""
    model, z, bounds = same_case
    multi = multi_start_joint_map(
        JointMapProblem(
            model, z, bounds, np.array([0.9]), np.array([8.0]), JointMapSettings(n_starts=6)
        )
    )
    ok0 = multi.runs[0].ok
    assert ok0.sum() >= 8
    assert np.all(multi.n_maxima[ok0] == 1)
    assert multi.paper_start_highest[ok0].all()
    assert np.all(multi.n_starts_ok[ok0] >= 2)  # the same maximum found again from elsewhere


def test_growth_model_has_no_unique_maximum_every_maximum_has_its_mirror():
    """Issue 47: -2 pi is unchanged by x -> -x, so no trajectory has one maximum; the image
    starts find the mirror of every maximum, at a gap of 0."""
    model = Growth()
    omega, x0 = np.array([0.5, 25.0]), np.array([5.0])
    z = trajectories(model, omega, x0, T=20, K=24, seed=0)
    bounds = model.prior_bounds(omega)
    multi = multi_start_joint_map(
        JointMapProblem(model, z, bounds, omega, x0, JointMapSettings(n_starts=8))
    )
    cols = multi.columns()
    k_max = int(multi.runs[0].ok.sum())
    assert k_max >= 16  # one start: most trajectories look observable
    assert int(cols["unique_max"].sum()) == 0  # |K^max_unique| = 0
    assert multi_start_summary(cols, JointMapSettings(n_starts=8))["K_max_unique"] == 0
    # the Halton starts take their states from two branches in turn
    assert multi.start_states[1:4] == ["sign_of_x0", "simulate", "sign_of_x0"]
    found = np.flatnonzero(multi.n_maxima >= 1)
    assert found.size >= k_max
    assert np.all(multi.n_maxima[found] % 2 == 0)  # maxima come in mirrored pairs
    for k in found:
        best = multi.maxima_log_post[k][0]
        assert abs(multi.log_post_gap[k]) <= 1e-9 * (1 + abs(best))  # gap 0: its mirror
        # every maximum's mirror image is one of the maxima, of the same height (other
        # ties exist too: x0 enters only through x_1's mean, which several x0 can match)
        points = [multi.runs[s].theta_hat[k] for s in multi.maxima_first_start[k]]
        for theta, value in zip(points, multi.maxima_log_post[k]):
            mirror = np.concatenate([theta[:2], -theta[2:]])
            gaps = [np.max(np.abs(mirror - other)) for other in points]
            twin = int(np.argmin(gaps))
            assert gaps[twin] < 1e-5 and np.max(np.abs(theta[2:])) > 1e-3  # not itself
            assert abs(multi.maxima_log_post[k][twin] - value) <= 1e-9 * (1 + abs(value))
    # the per-k columns the stage writes beside the joint-MAP table
    assert (cols["maxima_log_post"].map(len) == cols["n_maxima"]).all()
    assert (cols["n_starts_ok"] <= 8).all()
    assert set(cols["maxima_verdict"]) <= {"several", "none"}


def test_one_maximum_from_too_few_passing_starts_is_undetermined():
    from ssmobs.joint_map.multi_start import maxima_verdict

    verdict = maxima_verdict(np.array([1, 1, 1, 2, 0]), np.array([8, 4, 3, 8, 0]), 8, 0.5)
    assert verdict.tolist() == ["unique", "unique", "undetermined", "several", "none"]
    assert maxima_verdict(np.array([1]), np.array([1]), 8, 0.125).tolist() == ["unique"]
    with pytest.raises(ValueError, match="unique_min_share"):
        JointMapSettings(unique_min_share=0.0)
    runs = [fake_run([[1.0, 2.0]], [10.0], ["ok"])] + [
        fake_run([[5.0, 5.0]], [1.0], ["gradient"]) for _ in range(7)
    ]
    values, _, _ = distinct_maxima(runs, 0, JointMapSettings())
    assert values.size == 1  # one maximum, but 1 of 8 starts passed: not unique
    assert maxima_verdict(np.array([values.size]), np.array([1]), 8, 0.5)[0] == "undetermined"


def test_multiplicative_wrong_sign_maxima_show_up_as_extra_maxima():
    """(Sep, Multiplicative), the paper's start x = z: states of random sign, each kept on
    its side of zero (log x_t^2 in -2 pi), so the paper's start ends in a maximum of that
    sign pattern; the sign-consistent extra starts find higher ones with other patterns."""
    model = get_model("sep_mult")
    omega, x0 = np.array([0.9]), np.array([8.0])
    z = trajectories(model, omega, x0, T=20, K=10, seed=5)
    bounds = model.prior_bounds(omega, "half_line")
    multi = multi_start_joint_map(
        JointMapProblem(model, z, bounds, omega, x0, JointMapSettings(n_starts=6))
    )
    ok0 = multi.runs[0].ok
    assert ok0.sum() >= 8
    assert np.all(multi.n_maxima[ok0] >= 2)
    below = ok0 & ~multi.paper_start_highest
    assert below.sum() >= 8  # the paper's start ends below the highest maximum found
    # where it does, the higher maximum has another sign pattern of the states: the paper's
    # start's is a wrong-sign maximum
    best_start = np.array([s[0] for s in multi.maxima_first_start])
    for k in np.flatnonzero(below):
        best, paper = multi.runs[best_start[k]].theta_hat[k], multi.runs[0].theta_hat[k]
        assert np.any(np.sign(best[1:]) != np.sign(paper[1:]))


def test_sep_edge_of_the_support_is_reported_not_counted():
    """(Sep, a = b = 0.9, T = 75): many starts run to the singular edge b -> 1 of the joint
    posterior (Sec. IV.B); such trajectories have no maximum that passes, and a start that
    ends there higher than an interior maximum is flagged."""
    model = get_model("sep")
    omega, x0 = np.array([0.9, 0.9]), np.array([8.0])
    z = trajectories(model, omega, x0, T=75, K=30, seed=0)
    bounds = model.prior_bounds(omega, "restricted")
    multi = multi_start_joint_map(
        JointMapProblem(model, z, bounds, omega, x0, JointMapSettings(n_starts=4))
    )
    none = multi.n_maxima == 0
    assert none.sum() >= 5
    assert np.all(multi.n_starts_boundary[none] == 4)  # every start ended on the boundary
    assert multi.boundary_higher[none].all()
    for k in np.flatnonzero(multi.boundary_higher & ~none):
        best = -2 * multi.maxima_log_post[k][0]
        edge = [r.neg2_log_post[k] for r in multi.runs if r.status[k] == "boundary"]
        assert min(edge) < best


# --------------------------------------------------------------------------- stage and tables
def test_stage_writes_the_columns_and_the_summary(tmp_path):
    from ssmobs.config.scenario import entry_problems
    from ssmobs.config.stage_inputs import joint_map_inputs
    from ssmobs.design.trajectories import make_trajectories, write_trajectories
    from ssmobs.io import read_json, read_parquet
    from ssmobs.stages.joint_map import run_joint_map

    entry = {
        "name": "mult_small",
        "model": "sep_mult",
        "omega": {"a": 0.9},
        "x0": 8.0,
        "T": 12,
        "K": 4,
        "prior": "half_line",
        "joint_map_n_starts": 3,
    }
    sc = Scenario.from_config(entry)
    assert sc.joint_map_n_starts == 3
    rng = np.random.default_rng(2)
    write_trajectories(tmp_path / "t.nc", make_trajectories(sc, rng.standard_normal((24, 4))))
    config = {"joint_map": {}}
    full = dict(entry)
    assert entry_problems(full) == []  # fills in the schema's defaults

    def paths(stem: str) -> dict[str, Path]:
        names = ("table", "theta", "summary")
        return {n: tmp_path / f"{stem}.{e}" for n, e in zip(names, ("parquet", "nc", "json"))}

    inputs = joint_map_inputs(full, config, trajectories=str(tmp_path / "t.nc"))
    info = run_joint_map(inputs, paths("jm"))
    frame = read_parquet(tmp_path / "jm.parquet")
    summary = read_json(tmp_path / "jm.json")
    assert summary["n_starts"] == 3 == info["n_starts"]
    assert summary["K_max_unique"] == int(frame["unique_max"].sum())
    assert {
        "n_maxima",
        "log_post_gap",
        "paper_start_highest",
        "boundary_higher",
        "edge_supremum",
        "symmetric_twin",
        "starts_per_maximum",
    } <= set(frame.columns)
    assert [int(sum(c)) for c in frame["starts_per_maximum"]] == frame["n_starts_ok"].tolist()
    assert summary["K_symmetric_twin"] == 0  # the Multiplicative model has no symmetry found
    assert summary["K_edge_supremum"] == int(frame["edge_supremum"].sum())
    # without the override, the block's n_starts = 1: the paper's table, no extra column
    single = Scenario.from_config(
        {k: v for k, v in entry.items() if k != "joint_map_n_starts"} | {"name": "one"}
    )
    assert single.joint_map_n_starts is None
    one = {k: v for k, v in full.items() if k != "joint_map_n_starts"} | {"name": "one"}
    run_joint_map(joint_map_inputs(one, config, trajectories=str(tmp_path / "t.nc")), paths("one"))
    assert "n_maxima" not in read_parquet(tmp_path / "one.parquet").columns
    assert "K_max_unique" not in read_json(tmp_path / "one.json")


def section_rows(with_multi: bool) -> list[dict]:
    sc = same_a09(
        T=20, K=40, method="design", stan_init="random", joint_map=True, stan=False, paper_ref=""
    )
    joint = {"K": 40, "K_max": 30, "components": ["a", "x0"]}
    multi = {**joint, "n_starts": 8, "K_max_unique": 10, "K_max_several": 22}
    rows = [{"config": sc, "joint": joint, "marginal": None, "exact": None}]
    if with_multi:
        rows.append({"config": {**sc, "name": "m"}, "joint": multi, "marginal": None})
    return rows


def test_section_iv_gains_k_max_unique_only_with_multi_start():
    plain = section_iv(section_rows(False), {})
    assert "K_max_unique" not in plain.columns
    assert "K^max_unique/K (95 % CI)" not in section_iv_compact(section_rows(False), {})
    wide = section_iv(section_rows(True), {}).set_index("scenario")
    assert wide.loc["m", "K_max_unique"] == 10 and wide.loc["m", "K_max"] == 30
    assert wide.loc["m", "K_max_unique_frac"] == 0.25
    assert wide.loc["m", "K_max_unique_frac_lo95"] < 0.25 < wide.loc["m", "K_max_unique_frac_hi95"]
    assert np.isnan(wide.loc["s", "K_max_unique"]) and wide.loc["s", "joint_n_starts"] == 1
    compact = section_iv_compact(section_rows(True), {}).set_index("scenario")
    assert compact.loc["m", "K^max_unique/K (95 % CI)"].startswith("0.25 [")
    assert compact.loc["s", "K^max_unique/K (95 % CI)"] == ""


def test_no_start_lands_on_a_point_the_model_excludes():
    """Issue 47: the cubic sensor's states start at cbrt(z / b); the first Halton point of
    b's box (-1, 1) is b = 0 exactly, where that start is not finite: it is skipped."""
    from cubic_sensor_model import CubicSensor

    model = CubicSensor()
    omega, x0 = np.array([0.5, 0.8]), np.array([1.0])
    z = trajectories(model, omega, x0, T=8, K=6, seed=1)
    bounds = model.prior_bounds(omega)
    lo, hi = start_box(bounds, omega, x0, 3.0)
    raw = lo + halton(3, 3) * (hi - lo)
    assert raw[0, 0] == 0.0  # the plain sequence would start at b = 0
    multi = multi_start_joint_map(
        JointMapProblem(model, z, bounds, omega, x0, JointMapSettings(n_starts=5))
    )
    assert np.all(multi.starts[:, 0] != 0.0)
    assert len(np.unique(multi.starts, axis=0)) == 5
    assert all(np.all(r.status != "failed") for r in multi.runs[:5])
