"""NetCDF files without xarray (ssmobs.io.write_netcdf / read_netcdf): the same values,
dimensions and attributes as xarray writes and reads, in both directions."""

import subprocess
import sys

import numpy as np
import pytest
from ssmobs import io

xr = pytest.importorskip("xarray")

ATTRS = {"scenario": "same_T4", "T": 4, "b_max": float("nan"), "distance": 1.25e-3, "x0": "[8.0]"}


def variables():
    rng = np.random.default_rng(3)
    return {
        "k": (("k",), np.arange(5)),
        "component": (("component",), np.array(["a", "x_1", "omega_long_name"])),
        "theta_hat": (("k", "component"), rng.normal(size=(5, 3))),
        "status": (("k",), np.array(["ok", "failed", "ok", "", "ok"])),
        "x": (("k", "t"), np.array([[np.nan, -0.0, np.inf, 1e-300]] * 5)),
    }


def same_bits(a: np.ndarray, b: np.ndarray) -> bool:
    return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()


def test_round_trip_keeps_values_dimensions_and_attributes(tmp_path):
    io.write_netcdf(tmp_path / "a.nc", variables(), ATTRS)
    back = io.read_netcdf(tmp_path / "a.nc", required_vars=["theta_hat"])
    for name, (dims, values) in variables().items():
        assert back.dims[name] == dims
        assert same_bits(back[name], values), name
    assert back.attrs.keys() == ATTRS.keys()
    assert back.attrs["scenario"] == "same_T4" and back.attrs["T"] == 4
    assert np.isnan(back.attrs["b_max"]) and back.attrs["distance"] == 1.25e-3


def test_xarray_reads_what_we_write(tmp_path):
    io.write_netcdf(tmp_path / "a.nc", variables(), ATTRS)
    with xr.open_dataset(tmp_path / "a.nc", engine="h5netcdf") as opened:
        ds = opened.load()
    for name, (dims, values) in variables().items():
        assert ds[name].dims == dims
        if values.dtype.kind == "U":
            assert ds[name].values.tolist() == values.tolist()
        else:
            assert same_bits(ds[name].values, values), name
    assert ds.attrs["scenario"] == "same_T4" and ds.attrs["T"] == 4


def test_we_read_what_xarray_writes_as_xarray_reads_it(tmp_path):
    """Files made before this reader (xarray's writer, with its fill values) read the same."""
    data = variables()
    ds = xr.Dataset(
        {n: v for n, v in data.items() if n not in ("k", "component")},
        coords={"k": data["k"][1], "component": data["component"][1]},
        attrs=ATTRS,
    )
    ds.to_netcdf(tmp_path / "x.nc", engine="h5netcdf")
    with xr.open_dataset(tmp_path / "x.nc", engine="h5netcdf") as opened:
        theirs = opened.load()
    ours = io.read_netcdf(tmp_path / "x.nc")
    assert set(ours.variables) == set(theirs.variables)
    for name in theirs.variables:
        assert ours.dims[name] == theirs[name].dims
        if ours[name].dtype.kind == "U":
            assert ours[name].tolist() == theirs[name].values.tolist()
        else:
            assert same_bits(ours[name], theirs[name].values), name
    assert ours.attrs.keys() == theirs.attrs.keys()


def test_unequal_dimension_lengths_are_refused(tmp_path):
    with pytest.raises(ValueError, match="dimension k: length 4"):
        io.write_netcdf(
            tmp_path / "a.nc", {"a": (("k",), np.zeros(3)), "b": (("k",), np.zeros(4))}, {}
        )
    with pytest.raises(ValueError, match="2 dimension names for 1-d"):
        io.write_netcdf(tmp_path / "a.nc", {"a": (("k", "t"), np.zeros(3))}, {})
    assert not (tmp_path / "a.nc").exists()


def test_missing_variable_and_damaged_file_are_named(tmp_path):
    io.write_netcdf(tmp_path / "a.nc", variables(), ATTRS)
    with pytest.raises(io.CorruptFileError, match=r"a\.nc: missing variables \['z'\]"):
        io.read_netcdf(tmp_path / "a.nc", required_vars=["z"])
    (tmp_path / "b.nc").write_bytes((tmp_path / "a.nc").read_bytes()[:200])
    with pytest.raises(io.CorruptFileError, match=r"b\.nc: not a readable NetCDF file"):
        io.read_netcdf(tmp_path / "b.nc")


def test_reading_and_writing_do_not_import_xarray(tmp_path):
    """The point of the reader: a job that only reads or writes our files skips xarray."""
    path = str(tmp_path / "a.nc")
    code = (
        "import sys, numpy as np; from ssmobs import io; "
        f"io.write_netcdf({path!r}, {{'x': (('k',), np.arange(3.0))}}, {{'a': 1}}); "
        f"io.read_netcdf({path!r}); "
        "print('xarray' in sys.modules, 'pandas' in sys.modules)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["False", "False"]
