"""Native backend's program cache: entries are self-contained (they outlive the environment
that built them and run when moved), looking one up runs no compiler, entries get the
umask's mode, and a cache that cannot be written says which directory and what to do."""

from __future__ import annotations

import errno
import json
import os
import shutil
import stat
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from ssmobs.stan_backends import BackendError, SamplerSettings, native_build, stan_file
from ssmobs.stan_backends.native import NativeBackend
from ssmobs.stan_backends.native_run import read_draws_file
from test_backends import _data

pytestmark = pytest.mark.stan

#: what the driver needs from the wheel at run time
WHEEL_LIBS = ("libtbb.so.2",)

SMALL = SamplerSettings(chains=2, iter_warmup=150, iter_sampling=150, workers=1)
WORKFLOW_DIR = Path(__file__).resolve().parents[2] / "workflow"
#: the umask the fixture builds with (so the entry's mode is not mkdtemp's 0700 by luck)
BUILD_UMASK = 0o027


def _env_without_ld_path() -> dict[str, str]:
    return {k: v for k, v in os.environ.items() if k != "LD_LIBRARY_PATH"}


#: the tests of an entry built into a fresh cache (one program compiled, about 30-50 CPU-s):
#: the path of a cluster node without a compiler or a cache shared by several users, a rare
#: one, so in `make test-slow` (issue 48); the messages of an unwritable cache stay here
FRESH_BUILD = pytest.mark.slow


@pytest.fixture(scope="module")
def orphan_entry(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict]:
    """``same.stan`` built into a fresh cache by an "environment" (a copy of the httpstan
    package: its headers and stanc linked, its lib/ copied) that is deleted afterwards."""
    root = tmp_path_factory.mktemp("native-cache")
    real = native_build.httpstan_dir()
    fake = root / "doomed-venv" / "httpstan"
    (fake / "lib").mkdir(parents=True)
    (fake / "include").symlink_to(real / "include")
    (fake / "stanc").symlink_to(real / "stanc")
    for lib in (real / "lib").glob("*.so*"):
        shutil.copy2(lib, fake / "lib" / lib.name)
    cache = root / "cache"
    # the driver object is a build input shared by every program, not part of an entry:
    # copied from the user's cache it saves a compile of the driver (same sources, flags)
    driver = native_build.driver_object().parent
    shutil.copytree(driver, cache / "native" / driver.name)
    mp = pytest.MonkeyPatch()
    mp.setenv("SSMOBS_CACHE", str(cache))
    mp.setattr(native_build, "httpstan_dir", lambda: fake)
    old_umask = os.umask(BUILD_UMASK)
    try:
        marker = NativeBackend().compile(stan_file("same"))
    finally:
        os.umask(old_umask)
        mp.undo()
    shutil.rmtree(root / "doomed-venv")  # the environment that built the entry is gone
    return cache, marker


def _readelf_dynamic(exe: Path) -> str:
    if shutil.which("readelf") is None:
        pytest.skip("readelf (binutils) is not installed")
    return subprocess.run(
        ["readelf", "-d", str(exe)], capture_output=True, text=True, check=True
    ).stdout


def _run_driver(exe: Path, work: Path, **kw: str) -> subprocess.CompletedProcess:
    data = work / "data.json"
    data.write_text(json.dumps(_data("same", {"a": 0.9})))
    args = {"seed": "5", "chains": "2", "warmup": "100", "samples": "50", **kw}
    cmd = [str(exe), "--data", str(data), "--output", str(work / "draws.bin")]
    for k, v in args.items():
        cmd += [f"--{k}", v]
    return subprocess.run(cmd, capture_output=True, text=True, env=_env_without_ld_path())


@FRESH_BUILD
def test_entry_has_its_libraries_and_runpath_origin(orphan_entry, tmp_path):
    """RUNPATH is $ORIGIN only and TBB sits beside the executable; a copy of the entry
    moved elsewhere runs with LD_LIBRARY_PATH unset and loads TBB from the copy."""
    _, marker = orphan_entry
    entry = Path(marker["cache_dir"])
    exe = Path(marker["exe_file"])
    assert exe.parent == entry
    for lib in WHEEL_LIBS:
        assert (entry / lib).is_file(), lib
    dynamic = _readelf_dynamic(exe)
    assert "(RUNPATH)" in dynamic and "Library runpath: [$ORIGIN]" in dynamic, dynamic
    assert "(RPATH)" not in dynamic, dynamic
    assert "[libtbb.so.2]" in dynamic

    moved = tmp_path / "elsewhere" / "entry"
    shutil.copytree(entry, moved)
    if shutil.which("ldd"):
        ldd = subprocess.run(
            ["ldd", str(moved / "driver")],
            capture_output=True,
            text=True,
            env=_env_without_ld_path(),
        ).stdout
        assert f"libtbb.so.2 => {moved / 'libtbb.so.2'}" in ldd, ldd
        assert "not found" not in ldd, ldd
    out = _run_driver(moved / "driver", tmp_path)
    assert out.returncode == 0, out.stderr
    columns, values = read_draws_file(tmp_path / "draws.bin")
    assert values.shape == (2, 50, len(columns))


@FRESH_BUILD
def test_entry_outlives_the_environment_that_built_it(orphan_entry, monkeypatch, tmp_path):
    """Another environment (this one) finds the entry of a deleted one, uses it without
    rebuilding, and gets the same draws as a build of its own."""
    cache, marker = orphan_entry
    monkeypatch.setenv("SSMOBS_CACHE", str(cache))
    backend = NativeBackend(tmp_root=tmp_path)
    assert backend.compile(stan_file("same"))["cache_dir"] == marker["cache_dir"]
    data = _data("same", {"a": 0.9})
    draws = backend.sample(stan_file("same"), data, 11, SMALL)
    entries = sorted(p.name for p in (cache / "native").iterdir() if not p.name.startswith("."))
    # no rebuild: the program's entry and the driver's object file it was linked with
    assert [n for n in entries if not n.startswith("driver-")] == [Path(marker["cache_dir"]).name]
    assert len(entries) == 2
    monkeypatch.delenv("SSMOBS_CACHE")
    own = NativeBackend(tmp_root=tmp_path).sample(stan_file("same"), data, 11, SMALL)
    np.testing.assert_array_equal(draws.params["x"], own.params["x"])
    np.testing.assert_array_equal(draws.sample_stats["lp__"], own.sample_stats["lp__"])


@FRESH_BUILD
def test_lookup_needs_no_compiler(orphan_entry, tmp_path):
    """With no g++ on PATH (and no $CXX) a built program is found and runs."""
    cache, marker = orphan_entry
    empty_bin = tmp_path / "bin"
    empty_bin.mkdir()
    assert shutil.which("g++", path=str(empty_bin)) is None
    data = tmp_path / "data.json"
    data.write_text(json.dumps(_data("same", {"a": 0.9})))
    script = (
        "import json, sys\n"
        "from ssmobs.stan_backends import SamplerSettings, stan_file\n"
        "from ssmobs.stan_backends.native import NativeBackend\n"
        "b = NativeBackend()\n"
        "m = b.compile(stan_file('same'))\n"
        "d = b.sample(stan_file('same'), json.load(open(sys.argv[1])), 3,\n"
        "             SamplerSettings(chains=2, iter_warmup=50, iter_sampling=20))\n"
        "print(json.dumps({'marker': m, 'shape': list(d.params['x'].shape)}))\n"
    )
    env = {k: v for k, v in os.environ.items() if k not in ("CXX", "LD_LIBRARY_PATH", "PYTHONPATH")}
    env.update(PATH=str(empty_bin), SSMOBS_CACHE=str(cache), PYTHONPATH=str(WORKFLOW_DIR))
    out = subprocess.run(
        [sys.executable, "-c", script, str(data)], capture_output=True, text=True, env=env
    )
    assert out.returncode == 0, out.stderr[-3000:]
    result = json.loads(out.stdout.strip().splitlines()[-1])
    assert result["marker"]["cache_dir"] == marker["cache_dir"]
    assert result["marker"]["compiler"] == marker["compiler"] != "unknown"
    assert result["shape"] == [2, 20, 8]


@FRESH_BUILD
def test_build_record_names_the_compiler(orphan_entry):
    """The compiler's version is recorded at build time, not part of the key."""
    _, marker = orphan_entry
    record = json.loads((Path(marker["cache_dir"]) / "build.json").read_text())
    assert record["compiler_version"] == marker["compiler"] != "unknown"
    assert "compiler" not in native_build.build_key("x")


@FRESH_BUILD
def test_entry_mode_follows_the_umask(orphan_entry):
    """The entry (not mkdtemp's 0700) and its files get the mode the umask allows."""
    _, marker = orphan_entry
    entry = Path(marker["cache_dir"])
    expected_dir = 0o777 & ~BUILD_UMASK
    assert stat.S_IMODE(entry.stat().st_mode) == expected_dir
    assert stat.S_IMODE((entry / "driver").stat().st_mode) == expected_dir
    for lib in WHEEL_LIBS:
        assert stat.S_IMODE((entry / lib).stat().st_mode) == expected_dir
    assert stat.S_IMODE((entry / "build.json").stat().st_mode) == 0o666 & ~BUILD_UMASK


def _refuse_writes_under(monkeypatch: pytest.MonkeyPatch, root: Path) -> None:
    """Make directory creation and file opening for writing under ``root`` fail as on a
    read-only file system (tests run as root, which chmod cannot stop)."""
    real_mkdir, real_open = os.mkdir, os.open

    def inside(path: object) -> bool:
        return Path(os.fsdecode(path)).resolve().is_relative_to(root.resolve())

    def mkdir(path, *args, **kwargs):
        if inside(path):
            raise OSError(errno.EROFS, os.strerror(errno.EROFS), os.fsdecode(path))
        return real_mkdir(path, *args, **kwargs)

    def open_(path, flags, *args, **kwargs):
        if inside(path) and flags & (os.O_WRONLY | os.O_RDWR | os.O_CREAT):
            raise OSError(errno.EROFS, os.strerror(errno.EROFS), os.fsdecode(path))
        return real_open(path, flags, *args, **kwargs)

    monkeypatch.setattr(os, "mkdir", mkdir)
    monkeypatch.setattr(os, "open", open_)


@pytest.mark.parametrize("existing", [False, True], ids=["empty", "native-dir-exists"])
def test_read_only_cache_names_the_directory(tmp_path, monkeypatch, existing):
    cache = tmp_path / "ro-cache"
    if existing:
        (cache / "native").mkdir(parents=True)
    monkeypatch.setenv("SSMOBS_CACHE", str(cache))
    _refuse_writes_under(monkeypatch, cache)
    # io.file_lock opens its lock file with the builtin open, which does not go through
    # os.open: refuse that one as well
    import builtins

    real_builtin_open = builtins.open

    def builtin_open(file, mode="r", *args, **kwargs):
        if (
            isinstance(file, (str, os.PathLike))
            and Path(file).resolve().is_relative_to(cache.resolve())
            and any(c in mode for c in "wax+")
        ):
            raise OSError(errno.EROFS, os.strerror(errno.EROFS), os.fspath(file))
        return real_builtin_open(file, mode, *args, **kwargs)

    monkeypatch.setattr(builtins, "open", builtin_open)
    with pytest.raises(BackendError) as info:
        NativeBackend().compile(stan_file("same"))
    message = str(info.value)
    assert str(cache / "native") in message
    assert "SSMOBS_CACHE" in message
    assert "Read-only file system" in message


def test_real_read_only_directory(tmp_path, monkeypatch):
    """A cache on a file system that refuses writes even to root (sysfs, procfs)."""
    for candidate in (Path("/sys/ssmobs-cache"), Path("/proc/ssmobs-cache")):
        try:
            candidate.mkdir()
        except OSError as err:
            if err.errno in (errno.EROFS, errno.EACCES, errno.EPERM):
                break
            continue
        else:  # pragma: no cover - a writable /sys: leave nothing behind
            candidate.rmdir()
    else:
        pytest.skip("no read-only directory to try")
    monkeypatch.setenv("SSMOBS_CACHE", str(candidate))
    with pytest.raises(BackendError, match=r"(?s)cannot write the compiled-program cache.*"):
        NativeBackend().compile(stan_file("same"))


@FRESH_BUILD
def test_read_only_cache_with_the_entry_works(orphan_entry, monkeypatch):
    """A cache someone else filled and that this process cannot write is used as it is."""
    cache, marker = orphan_entry
    monkeypatch.setenv("SSMOBS_CACHE", str(cache))
    _refuse_writes_under(monkeypatch, cache)
    assert NativeBackend().compile(stan_file("same"))["exe_file"] == marker["exe_file"]
