"""Atomic writes, validated reads and design trajectories on disk."""

from __future__ import annotations

import errno
import os
from pathlib import Path

import numpy as np
import pytest
from factories import same_a09
from ssmobs import io
from ssmobs.config.scenario import Scenario
from ssmobs.design.disturbances import design_disturbances
from ssmobs.design.trajectories import make_trajectories, read_trajectories, write_trajectories
from ssmobs.models import get_model

pytestmark = pytest.mark.unit


def test_atomic_path_leaves_nothing_on_error(tmp_path):
    target = tmp_path / "out.json"
    with pytest.raises(RuntimeError):
        with io.atomic_path(target) as tmp:
            tmp.write_text("half")
            raise RuntimeError("killed")
    assert not target.exists()
    assert os.listdir(tmp_path) == []


def _fail(code: int):
    def fail(*args, **kwargs):
        raise OSError(code, os.strerror(code))

    return fail


@pytest.mark.parametrize("code", [errno.ENOSPC, errno.EROFS, errno.EACCES])
@pytest.mark.parametrize("step", ["mkstemp", "write", "fsync", "replace"])
def test_a_failed_write_names_the_file_and_keeps_the_errno(tmp_path, monkeypatch, step, code):
    import pandas as pd

    target = tmp_path / "sub" / "out.parquet"
    if step == "mkstemp":
        monkeypatch.setattr(io.tempfile, "mkstemp", _fail(code))
    elif step == "write":
        monkeypatch.setattr(pd.DataFrame, "to_parquet", _fail(code))
    else:
        monkeypatch.setattr(io.os, step, _fail(code))
    with pytest.raises(OSError) as err:
        io.write_parquet(target, pd.DataFrame({"x": [1.0]}))
    assert err.value.errno == code
    assert str(target) in str(err.value) and os.strerror(code) in str(err.value)
    assert isinstance(err.value.__cause__, OSError) and err.value.__cause__.errno == code
    assert isinstance(err.value, PermissionError) == (code == errno.EACCES)
    assert not target.exists() and io.temporaries(target) == []


def test_json_round_trip_and_corruption(tmp_path):
    path = tmp_path / "r.json"
    io.write_json(path, {"a": np.float64(1.5), "b": np.arange(3)})
    assert io.read_json(path, required=["a", "b"]) == {"a": 1.5, "b": [0, 1, 2]}
    path.write_text(path.read_text()[:7])
    with pytest.raises(io.CorruptFileError, match="r.json"):
        io.read_json(path)


def test_disturbances_round_trip_and_checksum(tmp_path):
    res = design_disturbances(4, 9, "design", 3)
    path = tmp_path / "d.nc"
    io.write_disturbances(path, res)
    matrix, attrs = io.read_disturbances(path, q=4, K=9)
    np.testing.assert_array_equal(matrix, res.matrix)
    assert attrs["method"] == "design" and attrs["seed"] == 3
    with pytest.raises(io.CorruptFileError, match="expected a 5 x 9"):
        io.read_disturbances(path, q=5, K=9)
    raw = bytearray(path.read_bytes())
    path.write_bytes(bytes(raw[: len(raw) // 2]))
    with pytest.raises(io.CorruptFileError, match="d.nc"):
        io.read_disturbances(path)


SCENARIO = Scenario.from_config(same_a09(T=3, method="design", seed=1))


def test_trajectories_follow_the_model_equations(tmp_path):
    rng = np.random.default_rng(0)
    matrix = rng.standard_normal((6, 4))
    traj = make_trajectories(SCENARIO, matrix)
    a, s = 0.9, np.sqrt(1 - 0.81)
    eta, eps = matrix[:3].T, matrix[3:].T
    x1 = a * 8 + s * eta[:, 0]
    np.testing.assert_allclose(traj.x[:, 0, 0], x1)
    np.testing.assert_allclose(traj.x[:, 1, 0], a * x1 + s * eta[:, 1])
    np.testing.assert_allclose(traj.z[:, :, 0], a * traj.x[:, :, 0] + s * eps)
    path = tmp_path / "t.nc"
    write_trajectories(path, traj)
    back = read_trajectories(path)
    np.testing.assert_array_equal(back.x, traj.x)
    np.testing.assert_array_equal(back.z, traj.z)
    assert back.model.slug == "same" and back.T == 3 and back.K == 4


def test_damaged_trajectories_detected(tmp_path):
    traj = make_trajectories(SCENARIO, np.ones((6, 4)))
    path = tmp_path / "t.nc"
    write_trajectories(path, traj)
    import xarray as xr

    with xr.open_dataset(path, engine="h5netcdf") as opened:
        ds = opened.load()
    ds["z"][0, 0, 0] = 99.0
    ds.to_netcdf(path, engine="h5netcdf")
    with pytest.raises(io.CorruptFileError, match="checksum"):
        read_trajectories(path)


@pytest.mark.parametrize(
    "slug,omega,x0",
    [
        ("sep_d2_p1", {"a": 0.9, "b": 0.8, "c": 0.7}, 8.0),
        ("sep_d1_p2", {"a": 0.6, "b": 0.5, "c": 0.9, "d": 0.8}, [8.0, 7.0]),
    ],
)
def test_disturbance_layout_state_first(slug, omega, x0):
    """Rows: eta_1..eta_T (p each) first, then eps_1..eps_T (d each), Sec. III.A."""
    model = get_model(slug)
    T, K = 3, 2
    q = (model.obs_dim + model.state_dim) * T
    matrix = np.arange(q * K, dtype=float).reshape(q, K)
    eta, eps = model.split_disturbances(matrix, T)
    assert eta.shape == (K, T, model.state_dim) and eps.shape == (K, T, model.obs_dim)
    np.testing.assert_array_equal(eta[1, 0], matrix[: model.state_dim, 1])
    np.testing.assert_array_equal(
        eps[0, 0], matrix[model.state_dim * T : model.state_dim * T + model.obs_dim, 0]
    )


def test_two_state_simulation_follows_eq_1():
    """(Sep, d=1, p=2): two AR(1) states and Z_t = a X_t1 + b X_t2 + sqrt(1-a^2-b^2) eps_t."""
    model = get_model("sep_d1_p2")
    rng = np.random.default_rng(0)
    eta, eps = rng.standard_normal((3, 4, 2)), rng.standard_normal((3, 4, 1))
    a, b, c, d = 0.6, 0.5, 0.9, 0.8
    x, z = model.simulate(np.array([a, b, c, d]), np.array([8.0, 7.0]), eta, eps)
    prev = np.tile([8.0, 7.0], (3, 1))
    coef = np.array([c, d])
    for t in range(4):
        prev = coef * prev + np.sqrt(1 - coef**2) * eta[:, t]
        np.testing.assert_allclose(x[:, t], prev)
    np.testing.assert_allclose(
        z[..., 0], a * x[..., 0] + b * x[..., 1] + np.sqrt(1 - a * a - b * b) * eps[..., 0]
    )


# ------------------------------------------------- issue 14: modes and stale temporaries
@pytest.fixture()
def umask():
    """Set the process umask for one test and restore it."""
    old = os.umask(0o022)
    os.umask(old)
    yield lambda mask: os.umask(mask)
    os.umask(old)


@pytest.mark.parametrize("mask", [0o022, 0o027, 0o002])
def test_atomic_outputs_get_the_mode_the_umask_implies(tmp_path, umask, mask):
    import pandas as pd
    from ssmobs.reports.figures import _plt, save_figure

    umask(mask)
    io.write_json(tmp_path / "a.json", {"x": 1})
    io.write_text(tmp_path / "b.md", "table\n")
    io.write_parquet(tmp_path / "c.parquet", pd.DataFrame({"x": [1.0]}))
    io.write_netcdf(tmp_path / "d.nc", {"x": (("k",), np.arange(3.0))}, {})
    plt = _plt()
    fig, _ = plt.subplots()
    save_figure(fig, [tmp_path / "e.png", tmp_path / "e.pdf"])
    plt.close(fig)
    modes = {p.name: p.stat().st_mode & 0o777 for p in tmp_path.iterdir()}
    assert modes == {
        name: 0o666 & ~mask for name in ["a.json", "b.md", "c.parquet", "d.nc", "e.png", "e.pdf"]
    }


def test_sweep_removes_only_our_stale_temporaries(tmp_path):
    target = tmp_path / "fig_x.png"
    stale = [tmp_path / ".fig_x.png.ab_cd123.png", tmp_path / ".fig_x.png.0123abcd.png"]
    keep = [
        tmp_path / ".fig_x.png.short.png",
        tmp_path / ".fig_y.png.ab_cd123.png",
        tmp_path / "fig_x.png.ab_cd123.png",
        tmp_path / ".fig_x.png.ab_cd123.pdf",
        tmp_path / ".fig_x.png.ab_cd123.png.keep",
    ]
    for p in stale + keep:
        p.write_bytes(b"")
    assert io.temporaries(target) == sorted(stale)
    assert io.sweep_temporaries([target, tmp_path / "missing_dir" / "t.csv"]) == sorted(stale)
    assert sorted(tmp_path.iterdir()) == sorted(keep)


def test_sweep_finds_what_a_killed_atomic_write_leaves(tmp_path):
    target = tmp_path / "table.csv"
    with io.atomic_path(target) as tmp:  # a writer killed here leaves tmp behind
        left = tmp
        assert io.temporaries(target) == [left]
        tmp.write_text("x\n")
    assert io.temporaries(target) == []
    assert target.read_text() == "x\n"


def test_a_file_without_its_checksum_cannot_be_trusted(tmp_path):
    """Found passed before (issue 35): a deleted ``.sha256`` counted as a match."""
    path = tmp_path / "trajectories.nc"
    path.write_bytes(b"some bytes")
    io.write_checksum(path)
    assert io.checksum_problem(path) is None
    path.write_bytes(b"other bytes")
    assert "does not match its checksum" in io.checksum_problem(path)
    io.checksum_path(path).unlink()
    assert "has no checksum trajectories.nc.sha256" in io.checksum_problem(path)
    path.unlink()
    assert io.checksum_problem(path) is None  # a missing file is remade by Snakemake


def test_recorded_checksums_find_every_damage_and_nothing_else(tmp_path, monkeypatch):
    """Issue 46: every job records its outputs' checksums; a file truncated, edited with
    its size kept or emptied is found, an intact, missing or unrecorded one is not."""
    monkeypatch.chdir(tmp_path)
    outside = tmp_path.parent / f"{tmp_path.name}_outside.csv"
    files = {
        "results/a/summary.json": b'{"a_mse": 0.00351}',
        "results/a/table.parquet": b"PAR1" + bytes(100),
        "paper_figures/x/table.csv": b"K,a\n4,0.1\n",
        "results/a/intact.json": b"{}",
        "results/a/gone.json": b"{}",
    }
    for name, content in files.items():
        Path(name).parent.mkdir(parents=True, exist_ok=True)
        Path(name).write_bytes(content)
    outside.write_bytes(b"1,2\n")
    io.record_checksums([*files, outside, "results/a/never_written.json"])
    assert io.damaged_files() == []
    Path("results/a/summary.json").write_bytes(b'{"a_mse": 0.50000}')  # same size
    Path("results/a/table.parquet").write_bytes(b"PAR1")  # truncated
    Path("paper_figures/x/table.csv").write_bytes(b"")  # emptied
    Path("results/a/gone.json").unlink()
    Path("results/a/unrecorded.json").write_text("{}")
    outside.write_bytes(b"1,3\n")
    found = dict(io.damaged_files())
    assert set(found) == {
        Path("results/a/summary.json"),
        Path("results/a/table.parquet"),
        Path("paper_figures/x/table.csv"),
        outside,
    }
    assert found[Path("paper_figures/x/table.csv")].endswith(
        "is empty (damaged or changed after it was written)"
    )
    # a job that writes the file again records it again
    io.record_checksums(["results/a/summary.json"])
    assert Path("results/a/summary.json") not in dict(io.damaged_files())
    outside.unlink()


def test_a_job_that_fails_records_no_checksum(tmp_path, monkeypatch):
    from ssmobs import log

    monkeypatch.chdir(tmp_path)
    Path("out.json").write_text("{}")
    monkeypatch.setattr(log, "_FAILED", ["RuntimeError"])
    log._record_outputs(["out.json"])
    assert not io.CHECKSUM_STORE.exists()
    monkeypatch.setattr(log, "_FAILED", [])
    log._record_outputs(["out.json"])
    assert io.checksum_record("out.json").read_text().endswith("  out.json\n")


def test_checked_json_finds_an_edit_and_a_missing_checksum(tmp_path):
    """Issue 46: the caches jobs keep beside their outputs (a point of the choice of K, a
    cell of a map) carry their content's checksum; an edit is refused, not read."""
    path = tmp_path / "K4.json"
    io.write_checked_json(path, {"K_i": 4, "v": np.float64(0.25), "nan": float("nan")})
    back = io.read_checked_json(path, required=["K_i"])
    assert back["K_i"] == 4 and back["v"] == 0.25 and io.CONTENT_CHECKSUM not in back
    path.write_text(path.read_text().replace("0.25", "0.5"))
    with pytest.raises(io.CorruptFileError, match="checksum does not match"):
        io.read_checked_json(path)
    io.write_json(path, {"K_i": 4})  # written before checksums: not trusted
    with pytest.raises(io.CorruptFileError, match="content_sha256"):
        io.read_checked_json(path)
