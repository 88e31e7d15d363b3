"""The opt-in precompiled Stan header of the native backend (``SSMOBS_STAN_PCH=1``, issue 63
item 4) gives the same executable, byte for byte, as a build without it (so it keys nothing),
and a real program's executable that was truncated or replaced in the cache is rebuilt, never
run, and samples the same draws again (issue 61 item 3).  Compiles a generated program twice
and the header once (a few CPU-minutes): `make test-slow`."""

from __future__ import annotations

import json
import resource
import shutil
from pathlib import Path

import numpy as np
import pytest
from ssmobs.nuts.stan_program import stan_program
from ssmobs.stan_backends import SamplerSettings, native_build
from ssmobs.stan_backends.cache import BUILD_RECORD
from ssmobs.stan_backends.native import NativeBackend
from test_backends import _data

pytestmark = [pytest.mark.stan, pytest.mark.slow]

SMALL = SamplerSettings(chains=2, iter_warmup=150, iter_sampling=150, workers=1)


def _children_cpu() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


@pytest.fixture(scope="module")
def two_builds(tmp_path_factory: pytest.TempPathFactory) -> dict[str, dict]:
    """The analytic ``same`` program built into two fresh caches, without and with the
    precompiled header (the driver's object file copied from the user's cache: the same
    input to both), with the compilers' CPU seconds of each build."""
    program, header = stan_program("same", "analytic")
    driver = native_build.driver_object().parent
    root = tmp_path_factory.mktemp("pch")
    out: dict[str, dict] = {}
    # "pch-again": a third cache holding the header the second build made: the program's
    # compile alone, as every program after the first pays it
    with pytest.MonkeyPatch.context() as mp:
        for name, pch in (("plain", "0"), ("pch", "1"), ("pch-again", "1")):
            cache = root / name
            shutil.copytree(driver, cache / "native" / driver.name)
            for entry in (root / "pch" / "native").glob("pch-*"):
                shutil.copytree(entry, cache / "native" / entry.name)
            mp.setenv("SSMOBS_CACHE", str(cache))
            mp.setenv(native_build.PCH_ENV, pch)
            before = _children_cpu()
            marker = NativeBackend().compile(program, user_header=header)
            out[name] = {"cache": cache, "marker": marker, "cpu_s": _children_cpu() - before}
    return out


def test_the_precompiled_header_gives_the_same_executable(two_builds):
    plain, pch = (Path(two_builds[k]["marker"]["exe_file"]) for k in ("plain", "pch"))
    assert plain.relative_to(two_builds["plain"]["cache"]) == pch.relative_to(
        two_builds["pch"]["cache"]
    )  # the same key
    assert plain.read_bytes() == pch.read_bytes()
    # the program's messages name its file, not the temporary directory it was built in
    assert b".tmp-" not in plain.read_bytes() and b"same_analytic.stan" in plain.read_bytes()
    (entry,) = (two_builds["pch"]["cache"] / "native").glob("pch-*")
    gch = entry / native_build.PCH_FILE
    record = json.loads((pch.parent / BUILD_RECORD).read_text())
    assert record["precompiled_header"] == str(entry / native_build.PCH_HEADER)
    assert json.loads((plain.parent / BUILD_RECORD).read_text())["precompiled_header"] is None
    assert "-Winvalid-pch" in record["command"][0]
    print(
        f"\nprecompiled header {gch.stat().st_size / 2**20:.0f} MiB; compiler CPU s: "
        f"without {two_builds['plain']['cpu_s']:.1f}, with (header built) "
        f"{two_builds['pch']['cpu_s']:.1f}, with (header cached) "
        f"{two_builds['pch-again']['cpu_s']:.1f}"
    )
    assert two_builds["pch-again"]["cpu_s"] < two_builds["plain"]["cpu_s"]


@pytest.mark.parametrize("damage", ["truncated", "replaced"])
def test_a_damaged_real_executable_is_rebuilt_and_samples_the_same_draws(
    two_builds, monkeypatch, tmp_path, damage
):
    program, header = stan_program("same", "analytic")
    data = _data("same", {"a": 0.9})
    monkeypatch.setenv("SSMOBS_CACHE", str(two_builds["plain"]["cache"]))
    expected = NativeBackend().sample(program, data, 3, SMALL, user_header=header)
    monkeypatch.setenv("SSMOBS_CACHE", str(two_builds["pch-again"]["cache"]))
    monkeypatch.setenv(native_build.PCH_ENV, "1")  # the rebuild takes the cached header
    exe = Path(two_builds["pch-again"]["marker"]["exe_file"])
    if damage == "truncated":
        exe.write_bytes(exe.read_bytes()[: exe.stat().st_size // 3])
    else:
        other = tmp_path / "other"
        shutil.copy2(shutil.which("true") or "/bin/true", other)
        other.replace(exe)
    draws = NativeBackend().sample(program, data, 3, SMALL, user_header=header)
    assert exe.read_bytes() == Path(two_builds["plain"]["marker"]["exe_file"]).read_bytes()
    for name, value in expected.params.items():
        np.testing.assert_array_equal(draws.params[name], value)
