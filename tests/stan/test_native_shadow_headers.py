"""The native backend's header that stands in for Stan's ``stan/model/gradient.hpp`` (one
message stream per thread instead of one per gradient call, the independent variables off
the chain stack; issue 49): programs built with it, autodiff and analytic, give the same
draws and the same messages, bit for bit, as programs built with Stan's own."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
from ssmobs.nuts.stan_program import stan_program
from ssmobs.stan_backends import SAMPLER_COLUMNS, SamplerSettings, native_build, stan_file
from ssmobs.stan_backends.cache import BUILD_RECORD
from ssmobs.stan_backends.native import NativeBackend
from ssmobs.stan_backends.native_run import run_driver
from test_backends import _data  # the same small data sets as the other backend tests

pytestmark = pytest.mark.stan

SMALL = SamplerSettings(chains=2, iter_warmup=150, iter_sampling=150, workers=1)

#: prints at every log density evaluation (so at every gradient of the sampler), and rejects
#: a part of the proposals, so messages are written before a normal return and before an
#: exception alike
PRINTING_PROGRAM = """\
parameters { real y; }
model {
  print("y = ", y);
  if (y > 1.2) reject("y above 1.2: ", y);
  y ~ normal(0, 1);
}
"""


def stock_headers(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    """From here on, builds see Stan's own headers only (an empty directory in place of
    ours)."""
    empty = tmp_path / "no_shadow_headers"
    empty.mkdir()
    monkeypatch.setattr(native_build, "SHADOW_INCLUDE_DIR", empty)


def include_dirs(marker: dict) -> list[str]:
    """The ``-I`` directories of the program's compile, in order, from its build record."""
    record = json.loads((Path(marker["cache_dir"]) / BUILD_RECORD).read_text())
    return [arg[2:] for arg in record["command"][0] if arg.startswith("-I")]


def test_shadow_header_comes_first_on_the_include_path():
    assert "stan/model/gradient.hpp" in native_build.shadow_headers()
    flags = [flag[2:] for flag in native_build.compile_flags() if flag.startswith("-I")]
    assert flags == [
        str(native_build.SHADOW_INCLUDE_DIR),
        str(native_build.httpstan_dir() / "include"),
    ]
    # The build cache is keyed by content, not by checkout: a program found there may have been
    # compiled from another clone, so its record is compared by the directories' own names.
    ours = NativeBackend().compile(stan_file("same"))
    recorded = [Path(directory) for directory in include_dirs(ours)]
    assert [recorded[0].parts[-3:], recorded[1].parts[-2:]] == [
        ("ssmobs", "stan_backends", "native_include"),
        ("httpstan", "include"),
    ]


# The two comparisons with Stan's own header build a driver and programs of their own (about
# 90 CPU-s on an empty cache): they guard the header against a change of it or of Stan, and
# run in `make test-slow`; `make test` keeps the include order above and the keys
# (tests/unit/test_cache_keys.py).
@pytest.mark.slow
@pytest.mark.parametrize("gradients", ["autodiff", "analytic"])
def test_same_draws_with_and_without_the_shadow_header(monkeypatch, tmp_path, gradients):
    data = _data("same", {"a": 0.9}, T=6)
    program, header = stan_program("same", gradients)
    ours_build = NativeBackend().compile(program, header)
    ours = NativeBackend().sample(program, data, 1234, SMALL, user_header=header)
    stock_headers(monkeypatch, tmp_path)
    stock_build = NativeBackend().compile(program, header)
    assert stock_build["cache_dir"] != ours_build["cache_dir"]  # not found under our key
    stock = NativeBackend().sample(program, data, 1234, SMALL, user_header=header)
    assert ours.params.keys() == stock.params.keys()
    for name in ours.params:
        np.testing.assert_array_equal(ours.params[name], stock.params[name], err_msg=name)
    for name in SAMPLER_COLUMNS:
        np.testing.assert_array_equal(
            ours.sample_stats[name], stock.sample_stats[name], err_msg=name
        )


def run_printing_program(program: Path, tmp_path: Path, threads: int) -> tuple[str, bytes]:
    """The driver's messages and draws file of 2 chains x (40 + 40) of PRINTING_PROGRAM."""
    marker = NativeBackend().compile(program)
    run = tmp_path / f"run-{len(list(tmp_path.glob('run-*')))}"
    run.mkdir()
    (run / "data.json").write_text("{}")
    cmd = [marker["exe_file"], "--data", str(run / "data.json"), "--seed", "11"]
    cmd += ["--chains", "2", "--warmup", "40", "--samples", "40", "--delta", "0.8"]
    cmd += ["--max-depth", "10", "--threads", str(threads), "--output", str(run / "draws.bin")]
    returncode, output = run_driver(cmd)
    assert returncode == 0, output
    return output, (run / "draws.bin").read_bytes()


def chain_lines(output: str, chain: int) -> list[str]:
    """One chain's messages, without the timings and with the program's path (a temporary
    build directory named by the build's key) left out."""
    return [
        re.sub(r"\(in '[^']*program\.stan'", "(in 'program.stan'", ln)
        for ln in output.splitlines()
        if ln.startswith(f"chain {chain}: ") and "seconds" not in ln
    ]


@pytest.mark.slow
@pytest.mark.parametrize("threads", [1, 2])
def test_messages_reach_the_logger_as_before(monkeypatch, tmp_path, threads):
    """A print in the model block runs at every gradient; with one stream per thread its
    text still reaches the logger once per gradient, before the rejection's message when
    the model rejects, and the two chains' streams do not mix when they run at once."""
    program = tmp_path / "printing.stan"
    program.write_text(PRINTING_PROGRAM)
    ours, ours_draws = run_printing_program(program, tmp_path, threads)
    stock_headers(monkeypatch, tmp_path)
    stock, stock_draws = run_printing_program(program, tmp_path, threads)
    assert ours_draws == stock_draws
    for chain in (1, 2):
        lines = chain_lines(ours, chain)
        assert lines == chain_lines(stock, chain)
        printed = [ln for ln in lines if ln.startswith(f"chain {chain}: y = ")]
        assert len(printed) > 80  # at least one gradient per iteration
        rejected = [i for i, ln in enumerate(lines) if "Exception: y above 1.2: " in ln]
        assert rejected, "no proposal was rejected: the test checks less than it says"
        # the print of the rejected evaluation was logged, with its value, before the
        # sampler's message about the exception
        for i in rejected:
            value = lines[i].split("y above 1.2: ")[1].split()[0]
            assert lines[i - 2] == f"chain {chain}: y = {value}"
