"""Stan backends: Draws shapes and layout, determinism, no files left behind, pool cap,
errors, and backend selection.

The PyStan tests sample tiny runs (2 chains, 150 + 150 iterations, T = 8).  The cmdstanpy
tests skip, with the reason, when CmdStan is not installed; with SSMOBS_REQUIRE_CMDSTAN=1
such a skip is a failure instead.
"""

from __future__ import annotations

import os
import tempfile
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from ssmobs.models import get_model
from ssmobs.stan_backends import (
    SAMPLER_COLUMNS,
    Draws,
    SamplerSettings,
    SamplingError,
    get_backend,
    have_cmdstan,
    stan_file,
)
from ssmobs.stan_backends import pystan as pystan_mod
from ssmobs.stan_backends.pystan import PyStanBackend

pytestmark = pytest.mark.stan

T = 8
SMALL = SamplerSettings(chains=2, iter_warmup=150, iter_sampling=150, workers=1)


def _data(slug: str, omega: dict, T: int = T, seed: int = 0) -> dict:
    model = get_model(slug)
    rng = np.random.default_rng(seed)
    x0 = np.full(model.state_dim, 8.0)
    eta = rng.standard_normal((1, T, model.state_dim))
    eps = rng.standard_normal((1, T, model.obs_dim))
    _, z = model.simulate(model.omega_array(omega), x0, eta, eps)
    return model.stan_data(z[0], model.prior_bounds(omega))


@pytest.fixture(scope="module")
def backend() -> PyStanBackend:
    return PyStanBackend()


def _fit_files(model_dir: Path) -> list[Path]:
    return sorted(model_dir.glob("fits/*")) if model_dir.is_dir() else []


def _check_draws(draws: Draws, settings: SamplerSettings, shapes: dict[str, tuple]) -> None:
    C, S = settings.chains, settings.iter_sampling
    assert {k: v.shape for k, v in draws.params.items()} == {
        k: (C, S) + shape for k, shape in shapes.items()
    }
    assert set(draws.sample_stats) == set(SAMPLER_COLUMNS)
    for name, arr in draws.sample_stats.items():
        assert arr.shape == (C, S), name
    assert draws.n_chains == C and draws.n_draws == S
    # after warmup the step size is fixed per chain: constant along draws, so the chain
    # axis is really the chain axis (PyStan's flat arrays interleave the chains)
    step = draws.sample_stats["stepsize__"]
    assert np.all(step == step[:, :1])
    assert len(np.unique(step[:, 0])) == C
    assert np.all(np.isin(draws.sample_stats["divergent__"], (0.0, 1.0)))


# ----------------------------------------------------------------------------- PyStan
@pytest.mark.pystan
def test_pystan_draws_deterministic_and_no_files_left(backend):
    sf = stan_file("same")
    data = _data("same", {"a": 0.9})
    marker = backend.compile(sf)
    assert marker["backend"] == "pystan" and marker["model_name"].startswith("models/")
    assert marker == backend.compile(sf)
    shared_model_dir = Path(marker["cache_dir"])
    shared_before = _fit_files(shared_model_dir)

    runs = [backend.sample(sf, data, seed=42, settings=SMALL) for _ in range(3)]
    for draws in runs:
        _check_draws(draws, SMALL, {"a": (), "x0": (), "x": (T,)})
        assert set(draws.timings) >= {"sample", "total"}
        assert 0 < draws.timings["sample"] <= draws.timings["total"]
    for other in runs[1:]:
        for name in runs[0].params:
            np.testing.assert_array_equal(runs[0].params[name], other.params[name])
        for name in SAMPLER_COLUMNS:
            np.testing.assert_array_equal(runs[0].sample_stats[name], other.sample_stats[name])
    different = backend.sample(sf, data, seed=43, settings=SMALL)
    assert not np.array_equal(different.params["a"], runs[0].params["a"])

    # nothing accumulates: no fits in the shared cache, none and no sockets in the private one
    assert _fit_files(shared_model_dir) == shared_before
    private = pystan_mod.private_cache().root
    assert private.is_dir()
    assert list(private.glob("httpstan/*/models/*/fits/*")) == []
    assert list(private.glob("httpstan_*.sock")) == []
    # the private model directory holds only symlinks into the shared cache
    private_models = list(private.glob("httpstan/*/models/*"))
    assert private_models and all(p.is_symlink() for d in private_models for p in d.iterdir())


@pytest.mark.pystan
def test_pystan_p2_layout_matches_arviz(backend):
    """Draws of matrix[T, 2] x agree with ArviZ's from_pystan (chain, draw, t, i)."""
    import arviz_base as az

    import stan

    omega = {"a": 0.5, "b": 0.6, "c": 0.8, "d": 0.6}
    data = _data("sep_d1_p2", omega, T=4)
    sf = stan_file("sep_d1_p2")
    with backend.session(sf):
        post = stan.build(sf.read_text(), data=data, random_seed=3)
        fit = post.sample(num_chains=3, num_warmup=100, num_samples=50, refresh=0)
    draws = pystan_mod.fit_to_draws(fit, n_chains=3, n_draws=50)
    idata = az.from_pystan(posterior=fit, posterior_model=post)
    for name in ("a", "b", "x0", "x"):
        np.testing.assert_array_equal(draws.params[name], idata.posterior[name].values)
    assert draws.params["x"].shape == (3, 50, 4, 2)
    np.testing.assert_array_equal(
        draws.sample_stats["energy__"], idata.sample_stats["energy"].values
    )


@pytest.mark.pystan
def test_pystan_pool_cap(backend, monkeypatch):
    """The chain pool has settings.workers processes and httpstan's pool is restored."""
    import httpstan.services_stub as ss

    made = []

    class Spy(ProcessPoolExecutor):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            made.append(self)
            self.max_seen = 0

        def submit(self, *args, **kwargs):
            fut = super().submit(*args, **kwargs)
            self.max_seen = max(self.max_seen, len(self._processes))
            return fut

        def shutdown(self, *args, **kwargs):
            self.max_seen = max(self.max_seen, len(self._processes or {}))
            super().shutdown(*args, **kwargs)

    monkeypatch.setattr(pystan_mod, "ProcessPoolExecutor", Spy)
    original = ss.executor
    data = _data("same", {"a": 0.9})
    settings = SamplerSettings(chains=3, iter_warmup=100, iter_sampling=100, workers=1)
    draws = backend.sample(stan_file("same"), data, seed=1, settings=settings)
    assert draws.params["a"].shape == (3, 100)
    assert len(made) == 1 and made[0]._max_workers == 1 and made[0].max_seen == 1
    settings2 = SamplerSettings(chains=3, iter_warmup=100, iter_sampling=100, workers=2)
    backend.sample(stan_file("same"), data, seed=1, settings=settings2)
    assert made[1]._max_workers == 2 and 1 <= made[1].max_seen <= 2
    assert ss.executor is original


@pytest.mark.pystan
def test_pystan_inits(backend):
    data = _data("sep", {"a": 0.9, "b": 0.9})
    sf = stan_file("sep")
    inits = [{"a": 0.5, "b": 0.5, "x0": 8.0}, {"a": 0.7}]  # partial dicts are fine
    draws = backend.sample(sf, data, seed=5, settings=SMALL, inits=inits)
    assert draws.params["b"].shape == (2, 150)
    with pytest.raises(ValueError, match="one dict per chain"):
        backend.sample(sf, data, seed=5, settings=SMALL, inits=[{}])


@pytest.mark.pystan
def test_pystan_sampling_error_leaves_nothing(backend):
    """An init outside the support makes Stan fail: SamplingError, and no files left."""
    data = _data("same", {"a": 0.9})
    with pytest.raises(SamplingError, match="same.stan"):
        backend.sample(
            stan_file("same"), data, seed=5, settings=SMALL, inits=[{"a": 1.5}, {"a": 1.5}]
        )
    private = pystan_mod.private_cache().root
    assert list(private.glob("httpstan/*/models/*/fits/*")) == []
    assert list(private.glob("httpstan_*.sock")) == []
    # the backend still works afterwards
    backend.sample(stan_file("same"), data, seed=5, settings=SMALL)


@pytest.mark.pystan
def test_pystan_bad_data_is_valueerror(backend):
    data = _data("same", {"a": 0.9})
    with pytest.raises(ValueError, match="data rejected"):
        backend.sample(
            stan_file("same"), {**data, "a_lower": 2.0, "a_upper": 3.0}, seed=1, settings=SMALL
        )
    bad = dict(data)
    del bad["z"]
    with pytest.raises(ValueError, match="data rejected"):
        backend.sample(stan_file("same"), bad, seed=1, settings=SMALL)
    with pytest.raises(ValueError, match="seed"):
        backend.sample(stan_file("same"), data, seed=-1, settings=SMALL)


@pytest.mark.parametrize(
    "slug,omega,shapes",
    [
        (
            "sep_d2_p1",
            {"a": 0.8, "b": 0.6, "c": 0.7},
            {"a": (), "b": (), "c": (), "x0": (), "x": (T,)},
        ),
        ("sep_ranwalk", {"a": 0.5}, {"a": (), "x0": (), "x": (T,)}),  # a in (0, inf)
        ("sep_mult", {"a": 0.5}, {"a": (), "x0": (), "x": (T,)}),
        (
            "sep_d1_p2",
            {"a": 0.5, "b": 0.6, "c": 0.8, "d": 0.6},
            {"a": (), "b": (), "c": (), "d": (), "x0": (2,), "x": (T, 2)},
        ),
    ],
)
@pytest.mark.pystan
def test_pystan_other_models_run(backend, slug, omega, shapes):
    draws = backend.sample(stan_file(slug), _data(slug, omega), seed=11, settings=SMALL)
    _check_draws(draws, SMALL, shapes)
    if slug == "sep_d1_p2":
        a, b = draws.params["a"], draws.params["b"]
        assert np.all(a**2 + b**2 < 1) and np.all(a > 0) and np.all(b > 0)
    if slug in ("sep_ranwalk", "sep_mult"):
        assert np.all(draws.params["a"] > 0)


# ----------------------------------------------------------------------------- cmdstanpy
def _require_cmdstan() -> None:
    if not have_cmdstan():
        reason = (
            "CmdStan is not installed (cmdstanpy finds no installation with bin/stanc;"
            " set $CMDSTAN or run `python -m cmdstanpy.install_cmdstan`)"
        )
        if os.environ.get("SSMOBS_REQUIRE_CMDSTAN") == "1":
            pytest.fail(f"SSMOBS_REQUIRE_CMDSTAN=1 but {reason}")
        pytest.skip(reason)


def test_cmdstanpy_run():
    _require_cmdstan()
    backend = get_backend("cmdstanpy")
    assert backend.name == "cmdstanpy"
    sf = stan_file("same")
    data = _data("same", {"a": 0.9})
    marker = backend.compile(sf)
    assert Path(marker["exe_file"]).is_file()
    assert not Path(marker["exe_file"]).is_relative_to(sf.parent)
    before = set(Path(tempfile.gettempdir()).glob("ssmobs-cmdstan-*"))
    runs = [backend.sample(sf, data, seed=42, settings=SMALL) for _ in range(2)]
    _check_draws(runs[0], SMALL, {"a": (), "x0": (), "x": (T,)})
    np.testing.assert_array_equal(runs[0].params["x"], runs[1].params["x"])
    after = set(Path(tempfile.gettempdir()).glob("ssmobs-cmdstan-*"))
    assert after <= before
    with pytest.raises(SamplingError):
        backend.sample(sf, data, seed=5, settings=SMALL, inits=[{"a": 1.5}, {"a": 1.5}])
    p2 = backend.sample(
        stan_file("sep_d1_p2"),
        _data("sep_d1_p2", {"a": 0.5, "b": 0.6, "c": 0.8, "d": 0.6}),
        seed=3,
        settings=SMALL,
    )
    _check_draws(p2, SMALL, {"a": (), "b": (), "c": (), "d": (), "x0": (2,), "x": (T, 2)})


def test_cmdstanpy_conversion_layout():
    """Draws from CmdStan's column layout (draws, chains, columns), no CmdStan needed."""
    from ssmobs.stan_backends.cmdstanpy import fit_to_draws
    from stanio import parse_header

    S, C, T2 = 5, 3, 4
    cols = (
        list(SAMPLER_COLUMNS)
        + ["a", "x0.1", "x0.2"]
        + [f"x.{t}.{i}" for i in (1, 2) for t in range(1, T2 + 1)]
    )  # CmdStan: column-major
    # value encodes (draw, chain, column) so every position can be checked
    arr = np.array(
        [[[1000 * s + 100 * c + j for j in range(len(cols))] for c in range(C)] for s in range(S)],
        dtype=float,
    )
    all_vars = parse_header(",".join(cols))
    fake = SimpleNamespace(
        draws=lambda concat_chains=False: arr,
        metadata=SimpleNamespace(
            stan_vars={k: v for k, v in all_vars.items() if not k.endswith("__")}
        ),
        method_variables=lambda: {
            k: v.extract_reshape(arr) for k, v in all_vars.items() if k.endswith("__")
        },
    )
    draws = fit_to_draws(fake)
    assert draws.params["x"].shape == (C, S, T2, 2)
    assert draws.params["x0"].shape == (C, S, 2)
    assert draws.params["a"].shape == (C, S)
    c, s, t, i = 2, 3, 2, 1  # x_{3,2} of chain 2, draw 3 (0-based indices)
    j = cols.index(f"x.{t + 1}.{i + 1}")
    assert draws.params["x"][c, s, t, i] == 1000 * s + 100 * c + j
    assert draws.sample_stats["energy__"][c, s] == 1000 * s + 100 * c + cols.index("energy__")


# ----------------------------------------------------------------------------- selection
def test_get_backend_errors(monkeypatch, tmp_path):
    with pytest.raises(ValueError, match="stan.backend.*'stan'"):
        get_backend("stan")
    monkeypatch.setenv("CMDSTAN", str(tmp_path / "nowhere"))
    assert have_cmdstan() is False
    with pytest.raises(ValueError) as err:
        get_backend("cmdstanpy")
    msg = str(err.value)
    for needle in ("stan.backend", "'cmdstanpy'", "install_cmdstan", "'native'", "$CMDSTAN"):
        assert needle in msg
    assert get_backend("auto").name == "native"
    assert get_backend("pystan").name == "pystan"
    # a directory with a makefile satisfies cmdstanpy but not have_cmdstan without bin/stanc
    fake = tmp_path / "cmdstan-2.36.0"
    fake.mkdir()
    (fake / "makefile").write_text("")
    monkeypatch.setenv("CMDSTAN", str(fake))
    assert have_cmdstan() is False
    (fake / "bin").mkdir()
    (fake / "bin" / "stanc").write_text("")
    assert have_cmdstan() is True
    assert get_backend("auto").name == "cmdstanpy"


def test_stan_file():
    for slug in ("same", "sep", "sep_d2_p1", "sep_d1_p2", "sep_ranwalk", "sep_mult"):
        assert stan_file(slug).is_file()
        assert stan_file(slug).parent.name == "stan"
    with pytest.raises(FileNotFoundError, match="nope"):
        stan_file("nope")


def test_pystan_gives_stanc_more_than_httpstans_one_second(monkeypatch):
    """httpstan runs stanc with timeout=1 s, which a loaded machine exceeds (a clean-clone
    `make run` failed so); the PyStan backend lengthens it for httpstan's module only."""
    import subprocess

    import httpstan.compile

    seen = []
    real_run = subprocess.run

    def spy(*args, **kwargs):
        seen.append(kwargs.get("timeout"))
        return real_run(*args, **kwargs)

    monkeypatch.setattr(httpstan.compile, "subprocess", subprocess)  # httpstan's own state
    monkeypatch.setattr(subprocess, "run", spy)
    pystan_mod._patient_stanc()
    pystan_mod._patient_stanc()  # idempotent
    cpp, _ = httpstan.compile.compile(
        "parameters { real y; } model { y ~ std_normal(); }", "model_timeout_check"
    )
    assert "model_timeout_check" in cpp
    assert seen == [pystan_mod.STANC_TIMEOUT]
    assert subprocess.run is spy  # the global module is untouched


def test_pystan_rebuilds_a_build_killed_after_its_module(tmp_path, monkeypatch):
    """httpstan writes the extension module, then stderr.log; a build killed in between left
    a module that httpstan loaded and then failed on (FileNotFoundError: stderr.log)."""
    import httpstan.cache
    import httpstan.models

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    code = "parameters { real y; } model { y ~ std_normal(); }  // killed-build check\n"
    program = tmp_path / "killed.stan"
    program.write_text(code)
    model_dir = httpstan.cache.model_directory(httpstan.models.calculate_model_name(code))
    model_dir.mkdir(parents=True)
    suffix = pystan_mod.EXTENSION_SUFFIXES[0]
    (model_dir / f"stan_services_leftover{suffix}").write_bytes(b"half a build")
    assert not pystan_mod._build_complete(model_dir)

    built = []

    def fake_build(code_, path):  # what a finished httpstan build leaves
        built.append(path)
        model_dir.mkdir(parents=True, exist_ok=True)
        (model_dir / f"stan_services_new{suffix}").write_bytes(b"module")
        (model_dir / "stderr.log").write_text("")

    monkeypatch.setattr(PyStanBackend, "_build_program", staticmethod(fake_build))
    PyStanBackend().compile(program)
    assert built == [program.resolve()]
    assert not (model_dir / f"stan_services_leftover{suffix}").exists()  # leftovers removed
    assert pystan_mod._build_complete(model_dir)
    PyStanBackend().compile(program)  # complete now: not built again
    assert len(built) == 1
