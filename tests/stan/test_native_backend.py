"""Native backend: same draws as PyStan for the same seed, errors that say what broke,
no files left behind, a compiled-program cache keyed by what determines the binary."""

from __future__ import annotations

import dataclasses
import json
import math
import os
import re
import stat
import subprocess
from pathlib import Path

import numpy as np
import pytest
from ssmobs.models import get_model
from ssmobs.nuts.batch import NutsBatch, run_trajectories
from ssmobs.nuts.record_cache import record_path
from ssmobs.stan_backends import (
    SAMPLER_COLUMNS,
    BackendError,
    SamplerSettings,
    SamplingError,
    get_backend,
    native_run,
    resolve_backend,
    stan_file,
)
from ssmobs.stan_backends.cache import publish_entry
from ssmobs.stan_backends.native import NativeBackend
from ssmobs.stan_backends.native_build import PROGRAM_ARTEFACTS
from ssmobs.stan_backends.native_run import LogDensities, columns_to_draws
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
@pytest.mark.pystan
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


@pytest.mark.pystan
def test_init_radius_reaches_the_sampler(native):
    """Random inits uniform on (-r, r) as Stan draws them: PyStan gives the same draws with
    another radius, and that radius gives other draws than Stan's default 2 (issue 20)."""
    data = _data("same", {"a": 0.9}, T=6)
    narrow = dataclasses.replace(SMALL, init_radius=0.5)
    a = native.sample(stan_file("same"), data, 1234, narrow)
    b = get_backend("pystan").sample(stan_file("same"), data, 1234, narrow)
    np.testing.assert_array_equal(a.params["x"], b.params["x"])
    default = native.sample(stan_file("same"), data, 1234, SMALL)
    assert not np.array_equal(a.params["x"], default.params["x"])


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
    dead = tmp_path / f"{native_run.TMP_PREFIX}999999999-abc"
    dead.mkdir()
    (dead / "data.json").write_text("{}")
    alive = tmp_path / f"{native_run.TMP_PREFIX}{os.getpid()}-xyz"
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
    # the build itself is tested on a fresh cache in test_native_cache.py; here only
    # which entry a changed program is built into (a recording build saves a compile)
    built: list[Path] = []

    def record_build(
        path: Path, code: str, cache_dir: Path, parts: dict, user_header: Path | None = None
    ) -> None:
        built.append(cache_dir)
        work = cache_dir.parent / "work"
        work.mkdir(parents=True)
        for name in PROGRAM_ARTEFACTS:
            (work / name).write_text("{}")
        publish_entry(work, cache_dir, {}, PROGRAM_ARTEFACTS)

    monkeypatch.setattr("ssmobs.stan_backends.native.build_program", record_build)
    other = NativeBackend().compile(copy)
    assert built == [Path(other["cache_dir"])]
    assert other["cache_dir"].startswith(str(tmp_path / "cache"))
    assert other["cache_dir"] != marker["cache_dir"]
    assert other["program_sha256"] != marker["program_sha256"]
    assert NativeBackend().compile(copy) == other and len(built) == 1  # found, not rebuilt


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
        batch = NutsBatch(
            model, stan_file("same"), z, z, model.prior_bounds([0.9]), [0.9], [8.0], "s", 1, SMALL
        )
        run_trajectories(batch, backend, [0, 1], records_dir=records)
    assert not record_path(records, 0).exists()


def test_log_density_output_parsed():
    text = (
        "param a\nparam x 3 2\nok -1.5 0.25 -2\nrejected lub_free: a is 2, but must be in [0, 1]\n"
        "ok -inf 0\n"
    )
    out = LogDensities.parse(text)
    assert out.param_names == ["a", "x"] and out.dims == [[], [3, 2]]
    assert out.values == [-1.5, None, None]
    assert out.gradients[0] == [0.25, -2.0] and out.gradients[1] is None
    assert out.messages[1].startswith("lub_free: a is 2")
    with pytest.raises(BackendError, match="unexpected line"):
        LogDensities.parse("nonsense\n")


def test_log_density_mode_rejects_points_outside_and_keeps_constants(native, tmp_path):
    data = _data("same", {"a": 0.5}, T=6)
    model = get_model("same")
    point = {"a": 0.5, "x0": 8.0, "x": [1.0] * 6}
    out = native.log_density(stan_file("same"), data, [point, {**point, "a": 1.5}])
    assert out.param_names == ["a", "x0", "x"] and out.dims == [[], [], [6]]
    assert out.values[1] is None and "a" in out.messages[1]
    theta = np.array([0.5, 8.0] + [1.0] * 6)
    bounds = model.prior_bounds({"a": 0.5})
    from ssmobs.models.log_posterior import log_posterior

    z = np.asarray(data["z"], dtype=float).reshape(6, 1)
    py = float(log_posterior(model, theta, z, bounds))
    # Stan keeps every normal's constant: 2 T of them, -log(2 pi) / 2 each
    assert out.values[0] - py == pytest.approx(-6 * math.log(2 * math.pi), abs=1e-9)


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


def test_columns_to_draws_uses_stans_names_complex():
    """Stan's names for complex values (``z.1.real``) are understood (stanio's parser)."""
    cols = ["lp__", "z.1.real", "z.1.imag", "z.2.real", "z.2.imag"]
    vals = np.arange(2 * 3 * len(cols), dtype=float).reshape(2, 3, len(cols))
    d = columns_to_draws(cols, vals)
    assert d.params["z"].shape == (2, 3, 2)
    assert d.params["z"][1, 2, 1] == complex(vals[1, 2, 3], vals[1, 2, 4])
    assert set(d.sample_stats) == {"lp__"}


# ----------------------------------------------------------- driver exit codes, files
def _run_exe(exe: str, *args: str) -> subprocess.CompletedProcess:
    base = ["--seed", "1", "--chains", "1", "--warmup", "20", "--samples", "10"]
    return subprocess.run([exe, *base, *args], capture_output=True, text=True)


def test_driver_separates_unreadable_from_rejected_data(native, tmp_path):
    """Exit 6: the data file cannot be opened or is not Stan JSON; 4: the model rejects
    the data; 6 also for an init file that cannot be read."""
    exe = native.compile(stan_file("same"))["exe_file"]
    out = str(tmp_path / "draws.bin")
    missing = _run_exe(exe, "--data", str(tmp_path / "absent.json"), "--output", out)
    assert missing.returncode == 6, missing.stderr
    assert "absent.json" in missing.stderr
    broken = tmp_path / "broken.json"
    broken.write_text('{"T": 8, "z": [1, 2,')
    parsed = _run_exe(exe, "--data", str(broken), "--output", out)
    assert parsed.returncode == 6, parsed.stderr
    rejected = tmp_path / "rejected.json"
    rejected.write_text(json.dumps(dict(_data("same", {"a": 0.9}), a_lower=0.5, a_upper=0.2)))
    judged = _run_exe(exe, "--data", str(rejected), "--output", out)
    assert judged.returncode == 4, judged.stderr
    good = tmp_path / "good.json"
    good.write_text(json.dumps(_data("same", {"a": 0.9})))
    init = _run_exe(exe, "--data", str(good), "--output", out, "--init", str(broken))
    assert init.returncode == 6, init.stderr
    assert not Path(out).exists()


def test_unreadable_data_fails_the_job_not_the_trajectory(tmp_path, monkeypatch):
    """A data file the driver cannot read raises BackendError (never a per-trajectory
    record), unlike data the model rejects (ValueError)."""
    backend = NativeBackend(tmp_root=tmp_path)
    real_popen = subprocess.Popen

    def popen_without_data(args, *rest, **kwargs):
        if isinstance(args, list) and str(args[0]).endswith("/driver") and "--data" in args:
            Path(args[args.index("--data") + 1]).unlink()  # swept under the driver
        return real_popen(args, *rest, **kwargs)

    monkeypatch.setattr(subprocess, "Popen", popen_without_data)
    with pytest.raises(BackendError, match=r"exit code 6[\s\S]*cannot read .*data\.json"):
        backend.sample(stan_file("same"), _data("same", {"a": 0.9}), 1, SMALL)


def _draws_file(path: Path, header: str, values: np.ndarray, length: int | None = None) -> Path:
    text = header.encode()
    n = len(text) if length is None else length
    path.write_bytes(
        native_run.MAGIC + n.to_bytes(4, "little") + text + values.astype("<f8").tobytes()
    )
    return path


def test_draws_file_written_little_endian(native, tmp_path):
    """The driver's file declares its byte order; header length and values are
    little-endian (what the reader assumes on any host)."""
    exe = native.compile(stan_file("same"))["exe_file"]
    data = tmp_path / "data.json"
    data.write_text(json.dumps(_data("same", {"a": 0.9})))
    out = tmp_path / "draws.bin"
    run = _run_exe(exe, "--data", str(data), "--output", str(out))
    assert run.returncode == 0, run.stderr
    raw = out.read_bytes()
    n = int.from_bytes(raw[8:12], "little")
    header = raw[12 : 12 + n].decode()
    assert header.startswith("byteorder=little\nchains=1\ndraws=10\ncolumns=lp__,")
    columns, values = native_run.read_draws_file(out)
    assert values.shape == (1, 10, len(columns))
    stepsize = values[0, :, columns.index("stepsize__")]
    assert np.all(stepsize > 0) and np.all(stepsize == stepsize[0])


@pytest.mark.parametrize(
    "header, length, field",
    [
        ("byteorder=little\nchains=2\ndraws=3\ncolumns=lp__,x\n", None, None),
        ("chains=2\ndraws=3\ncolumns=lp__,x\n", None, "byteorder: missing"),
        ("byteorder=big\nchains=2\ndraws=3\ncolumns=lp__,x\n", None, "byteorder: 'big'"),
        ("byteorder=little\ndraws=3\ncolumns=lp__,x\n", None, "chains: missing"),
        ("byteorder=little\nchains=two\ndraws=3\ncolumns=lp__,x\n", None, "chains: 'two'"),
        ("byteorder=little\nchains=2\ndraws=0\ncolumns=lp__,x\n", None, "draws: '0'"),
        ("byteorder=little\nchains=2\ndraws=-3\ncolumns=lp__,x\n", None, "draws: '-3'"),
        ("byteorder=little\nchains=2\ndraws=3\n", None, "columns: missing"),
        ("byteorder=little\nchains=2\ndraws=3\ncolumns=lp__,,x\n", None, "columns: empty"),
        ("byteorder=little\nchains=2\ndraws=3\ncolumns=lp__,x\nx=1\n", None, "x: unknown"),
        ("byteorder=little\nchains=2\nchains=2\ndraws=3\ncolumns=lp__,x\n", None, "chains: given"),
        ("byteorder=little\nchains=2\ndraws=3\ncolumns=lp__,x\nnonsense\n", None, "header: line"),
        ("byteorder=little\nchains=2\ndraws=4\ncolumns=lp__,x\n", None, "values: 96 bytes"),
        ("byteorder=little\nchains=2\ndraws=3\ncolumns=lp__,x\n", 10**6, "header length"),
    ],
)
def test_draws_file_header_checked(tmp_path, header, length, field):
    values = np.arange(12, dtype=float)  # 2 chains x 3 draws x 2 columns
    path = _draws_file(tmp_path / "draws.bin", header, values, length)
    if field is None:
        columns, arr = native_run.read_draws_file(path)
        assert columns == ["lp__", "x"]
        np.testing.assert_array_equal(arr, values.reshape(2, 3, 2))
        return
    with pytest.raises(BackendError, match=re.escape(field)):
        native_run.read_draws_file(path)


def test_draws_file_magic_and_truncation(tmp_path):
    bad = tmp_path / "bad.bin"
    bad.write_bytes(b"NOTDRAWS" + bytes(8))
    with pytest.raises(BackendError, match="magic"):
        native_run.read_draws_file(bad)
    bad.write_bytes(native_run.MAGIC + b"\x01")
    with pytest.raises(BackendError, match="header length"):
        native_run.read_draws_file(bad)
    bad.write_bytes(native_run.MAGIC + (2).to_bytes(4, "little") + b"\xff\xfe")
    with pytest.raises(BackendError, match="header: not UTF-8"):
        native_run.read_draws_file(bad)
