"""Native backend: same draws as PyStan for the same seed, errors that say what broke,
no files left behind, a compiled-program cache keyed by what determines the binary."""

from __future__ import annotations

import math
import os
import stat
from pathlib import Path

import numpy as np
import pytest
from ssmobs.models import get_model
from ssmobs.nuts_stage import run_trajectories
from ssmobs.record_cache import record_path
from ssmobs.stan_backends import (
    SAMPLER_COLUMNS,
    BackendError,
    SamplerSettings,
    SamplingError,
    get_backend,
    resolve_backend,
    stan_file,
)
from ssmobs.stan_backends import native as native_mod
from ssmobs.stan_backends.native import NativeBackend, columns_to_draws
from test_backends import _data  # the same small data sets as the other backend tests

pytestmark = pytest.mark.stan

SMALL = SamplerSettings(chains=2, iter_warmup=150, iter_sampling=150, workers=1)


@pytest.fixture(scope="module")
def native() -> NativeBackend:
    return NativeBackend()


def test_auto_is_native_without_cmdstan(monkeypatch):
    monkeypatch.setattr("ssmobs.stan_backends.have_cmdstan", lambda: False)
    assert resolve_backend("auto") == "native"
    assert get_backend("auto").name == "native"


@pytest.mark.parametrize(
    "slug, omega, inits",
    [
        ("same", {"a": 0.9}, False),
        ("same", {"a": 0.9}, True),
        ("sep_d1_p2", {"a": 0.6, "b": 0.5, "c": 0.9, "d": 0.9}, False),
    ],
)
def test_same_draws_as_pystan(native, slug, omega, inits):
    """Bit-identical draws and sampler columns for the same seed (chain ids 1..C)."""
    pystan = get_backend("pystan")
    data = _data(slug, omega, T=6)
    init = None
    if inits:
        init = [{"a": 0.8, "x0": 7.0, "x": [1.0] * 6} for _ in range(SMALL.chains)]
    a = native.sample(stan_file(slug), data, 1234, SMALL, init)
    b = pystan.sample(stan_file(slug), data, 1234, SMALL, init)
    assert a.params.keys() == b.params.keys()
    for name in a.params:
        assert a.params[name].shape == b.params[name].shape, name
        np.testing.assert_array_equal(a.params[name], b.params[name], err_msg=name)
    for name in SAMPLER_COLUMNS:
        np.testing.assert_array_equal(a.sample_stats[name], b.sample_stats[name], err_msg=name)


def test_threads_do_not_change_draws(native):
    data = _data("same", {"a": 0.9})
    one = native.sample(stan_file("same"), data, 7, SMALL)
    two = native.sample(
        stan_file("same"),
        data,
        7,
        SamplerSettings(chains=2, iter_warmup=150, iter_sampling=150, workers=2),
    )
    np.testing.assert_array_equal(one.params["x"], two.params["x"])
    assert one.params["x"].shape == (2, 150, 8)
    assert one.timings["sample_cpu"] > 0


def test_no_temporary_files_left(native, tmp_path):
    backend = NativeBackend(tmp_root=tmp_path)
    backend.sample(stan_file("same"), _data("same", {"a": 0.9}), 3, SMALL)
    assert list(tmp_path.iterdir()) == []


def test_stale_temporaries_swept(tmp_path):
    dead = tmp_path / f"{native_mod.TMP_PREFIX}999999999-abc"
    dead.mkdir()
    (dead / "data.json").write_text("{}")
    alive = tmp_path / f"{native_mod.TMP_PREFIX}{os.getpid()}-xyz"
    alive.mkdir()
    backend = NativeBackend(tmp_root=tmp_path)
    backend.sample(stan_file("same"), _data("same", {"a": 0.9}), 3, SMALL)
    assert not dead.exists() and alive.exists()


def test_compile_error_shows_stanc_message(tmp_path):
    bad = tmp_path / "bad.stan"
    bad.write_text("parameters { real y; }\nmodel { y ~ normal(0, 1) }\n")  # missing ';'
    with pytest.raises(RuntimeError, match=r"stanc rejected .*bad\.stan[\s\S]*Syntax error"):
        NativeBackend().compile(bad)


def test_cache_keyed_by_program_not_environment(native, tmp_path, monkeypatch):
    marker = native.compile(stan_file("same"))
    assert Path(marker["exe_file"]).is_file()
    assert "native" in Path(marker["cache_dir"]).parts
    assert str(Path(os.sys.prefix)) not in marker["cache_dir"]
    # a changed program gets its own directory; the same text the same one
    copy = tmp_path / "same.stan"
    copy.write_text(stan_file("same").read_text())
    assert NativeBackend().compile(copy)["cache_dir"] == marker["cache_dir"]
    copy.write_text(stan_file("same").read_text() + "\n// changed\n")
    monkeypatch.setenv("SSMOBS_CACHE", str(tmp_path / "cache"))
    other = NativeBackend().compile(copy)
    assert other["cache_dir"].startswith(str(tmp_path / "cache"))
    assert other["program_sha256"] != marker["program_sha256"]


def test_initialisation_failure_is_a_sampling_error(native):
    data = _data("same", {"a": 0.9})
    init = [{"a": 5.0, "x0": 0.0, "x": [0.0] * 8}] * 2  # outside the support of a
    with pytest.raises(SamplingError, match="chain 1"):
        native.sample(stan_file("same"), data, 1, SMALL, init)


def test_data_rejected_is_a_value_error(native):
    data = dict(_data("same", {"a": 0.9}), a_lower=0.5, a_upper=0.2)
    with pytest.raises(ValueError, match="data rejected"):
        native.sample(stan_file("same"), data, 1, SMALL)


def _broken_driver(tmp_path: Path) -> Path:
    script = tmp_path / "driver"
    script.write_text(
        "#!/bin/sh\necho 'driver: error while loading shared libraries: "
        "libtbb.so.2: cannot open shared object file' >&2\nexit 127\n"
    )
    script.chmod(script.stat().st_mode | stat.S_IXUSR)
    return script


def test_missing_library_fails_the_job_not_the_trajectory(tmp_path):
    """A driver that cannot start raises BackendError and no record is written."""
    backend = NativeBackend()
    marker = backend.compile(stan_file("same"))
    backend._markers = {
        k: dict(v, exe_file=str(_broken_driver(tmp_path))) for k, v in backend._markers.items()
    }
    assert marker["backend"] == "native"
    with pytest.raises(BackendError, match="libtbb.so.2"):
        backend.sample(stan_file("same"), _data("same", {"a": 0.9}), 1, SMALL)
    model = get_model("same")
    z = np.random.default_rng(0).standard_normal((2, 5, 1))
    records = tmp_path / "records"
    with pytest.raises(BackendError):
        run_trajectories(
            model,
            backend,
            stan_file("same"),
            z,
            z,
            [0, 1],
            model.prior_bounds([0.9]),
            [0.9],
            [8.0],
            "s",
            1,
            sampler=SMALL,
            records_dir=records,
        )
    assert not record_path(records, 0).exists()


def test_columns_to_draws_column_major():
    """Matrix columns m.i.j come column-major (Stan's order) and land at [..., i-1, j-1]."""
    cols = ["lp__", "m.1.1", "m.2.1", "m.1.2", "m.2.2", "m.1.3", "m.2.3", "s"]
    vals = np.arange(2 * 3 * len(cols), dtype=float).reshape(2, 3, len(cols))
    d = columns_to_draws(cols, vals)
    assert d.params["m"].shape == (2, 3, 2, 3)
    assert d.params["m"][1, 2, 1, 0] == vals[1, 2, cols.index("m.2.1")]
    assert d.params["m"][0, 1, 0, 2] == vals[0, 1, cols.index("m.1.3")]
    assert d.params["s"].shape == (2, 3)
    assert math.isclose(d.sample_stats["lp__"][1, 1], vals[1, 1, 0])
