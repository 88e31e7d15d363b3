"""Compiled files in the cache carry a checksum written at build time and are verified before
each use (issue 61, item 3): a native program's executable and libraries, the native
driver's object file, a cmdstanpy executable and the LCD kernel library.  Replaced (with its
file time kept), truncated, one byte flipped or without its checksum: rebuilt, never run;
where it cannot be rebuilt, refused in one line naming the file.  The builds are faked here
(no compile); tests/stan/test_precompiled_header.py does it on a real program."""

from __future__ import annotations

import errno
import os
import shutil
import stat
import tempfile
from collections.abc import Callable
from pathlib import Path

import cmdstanpy
import pytest
from ssmobs import io
from ssmobs.design import lcd_native
from ssmobs.stan_backends import BackendError, SamplerSettings, cache, native_build
from ssmobs.stan_backends.cmdstanpy import CmdStanPyBackend
from ssmobs.stan_backends.native import NativeBackend

pytestmark = pytest.mark.stan

SMALL = SamplerSettings(chains=1, iter_warmup=10, iter_sampling=10, workers=1)


def _script(path: Path, body: str) -> None:
    path.write_text(f"#!/bin/sh\n{body}\n")
    path.chmod(0o755)


def flip_byte(path: Path) -> None:
    """One byte changed in the middle, file times kept."""
    st = path.stat()
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0x01
    path.write_bytes(bytes(data))
    os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns))


def truncate(path: Path) -> None:
    """The first half of the file kept, file times kept."""
    st = path.stat()
    path.write_bytes(path.read_bytes()[: st.st_size // 2])
    os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns))


def replace(path: Path, other: bytes) -> None:
    """Another file of the same size put in its place by a rename, file times kept."""
    st = path.stat()
    data = path.read_bytes()
    other = (other + data)[: len(data)]
    tmp = path.with_name(path.name + ".new")
    tmp.write_bytes(other)
    tmp.chmod(stat.S_IMODE(st.st_mode))
    os.utime(tmp, ns=(st.st_atime_ns, st.st_mtime_ns))
    os.replace(tmp, path)


def drop_checksum(path: Path) -> None:
    io.checksum_path(path).unlink()


DAMAGE: dict[str, Callable[[Path], None]] = {
    "flipped-byte": flip_byte,
    "truncated": truncate,
    "replaced": lambda p: replace(p, b'#!/bin/sh\ntouch "$0.tampered-ran"\nexit 0\n'),
    "no-checksum": drop_checksum,
}


# --------------------------------------------------------------------------- the cache
def test_an_entry_is_complete_only_while_its_files_match_their_checksums(tmp_path):
    work, entry = tmp_path / "work", tmp_path / "entry"
    work.mkdir()
    (work / "exe").write_bytes(b"\x7fELF" + bytes(range(256)) * 40)
    cache.publish_entry(work, entry, {"key": "k"}, ("exe",))
    assert io.checksum_path(entry / "exe").is_file()
    assert cache.entry_complete(entry, "exe") and cache.entry_problem(entry, "exe") is None
    for name, damage in DAMAGE.items():
        good = (entry / "exe").read_bytes()
        damage(entry / "exe")
        problem = cache.entry_problem(entry, "exe")
        assert not cache.entry_complete(entry, "exe"), name
        assert problem is not None and str(entry / "exe") in problem and "\n" not in problem
        (entry / "exe").write_bytes(good)
        io.write_checksum(entry / "exe")
        assert cache.entry_complete(entry, "exe"), name
    (entry / "exe").unlink()
    assert cache.entry_problem(entry, "exe") == f"{entry / 'exe'} is missing"


def test_a_file_is_hashed_once_while_its_stat_stays(tmp_path, monkeypatch):
    """The per-use check costs a ``stat`` once the file was hashed in this process; a
    rewrite with the same size and file time is still seen (inode, change time)."""
    path = tmp_path / "exe"
    path.write_bytes(bytes(range(256)) * 100)
    io.write_checksum(path)
    hashed: list[Path] = []
    real = cache.checksum_problem
    monkeypatch.setattr(cache, "checksum_problem", lambda p: hashed.append(p) or real(p))
    assert cache.verified(path) and cache.verified(path) and cache.verified(path)
    assert hashed == [path]
    flip_byte(path)
    assert not cache.verified(path)
    assert len(hashed) == 2


# --------------------------------------------------------------------------- native programs
class FakeProgramBuild:
    """Stands in for :func:`native_build.build_program`: publishes an entry whose driver is
    a shell script that writes a file when run (and stops at the usage check)."""

    def __init__(self) -> None:
        self.builds = 0
        self.fail_with: Exception | None = None

    def __call__(
        self, path: Path, code: str, cache_dir: Path, parts: dict, user_header: Path | None = None
    ) -> None:
        if self.fail_with is not None:
            raise self.fail_with
        self.builds += 1
        work = cache.new_build_dir(cache_dir)
        _script(work / native_build.EXE_NAME, 'touch "$0.good-ran"\nexit 2')
        for lib in native_build.RUNTIME_LIBS:
            (work / lib).write_bytes(b"\x7fELF library " + bytes(range(256)) * 10)
        cache.publish_entry(work, cache_dir, {**parts}, native_build.PROGRAM_ARTEFACTS)


@pytest.fixture
def fake_native(tmp_path, monkeypatch) -> FakeProgramBuild:
    monkeypatch.setenv("SSMOBS_CACHE", str(tmp_path / "cache"))
    fake = FakeProgramBuild()
    monkeypatch.setattr("ssmobs.stan_backends.native.build_program", fake)
    return fake


@pytest.fixture
def program(tmp_path) -> Path:
    path = tmp_path / "prog.stan"
    path.write_text("parameters { real y; }\nmodel { y ~ normal(0, 1); }\n")
    return path


@pytest.mark.parametrize("what", ["exe", "lib"])
@pytest.mark.parametrize("damage", list(DAMAGE))
def test_a_damaged_native_program_is_rebuilt_never_run(fake_native, program, damage, what):
    backend = NativeBackend()
    marker = backend.compile(program)
    exe = Path(marker["exe_file"])
    target = exe if what == "exe" else exe.parent / native_build.RUNTIME_LIBS[0]
    assert fake_native.builds == 1
    assert backend.compile(program) == marker and fake_native.builds == 1  # found, verified
    DAMAGE[damage](target)
    # the same backend (its marker remembered) and a new one (another job) both rebuild
    with pytest.raises(BackendError, match="bad arguments"):  # the rebuilt fake driver ran
        backend.sample(program, {}, 1, SMALL)
    assert fake_native.builds == 2
    assert not Path(f"{exe}.tampered-ran").exists()
    assert Path(f"{exe}.good-ran").exists()
    DAMAGE[damage](target)
    assert NativeBackend().compile(program) == marker and fake_native.builds == 3
    assert cache.entry_complete(exe.parent, *native_build.PROGRAM_ARTEFACTS)


def test_a_damaged_native_program_that_cannot_be_rebuilt_is_refused(fake_native, program):
    marker = NativeBackend().compile(program)
    exe = Path(marker["exe_file"])
    replace(exe, b'#!/bin/sh\ntouch "$0.tampered-ran"\nexit 0\n')
    fake_native.fail_with = BackendError("cannot run g++: [Errno 2] No such file\nmore lines")
    with pytest.raises(BackendError) as err:
        NativeBackend().sample(program, {}, 1, SMALL)
    message = str(err.value)
    assert "\n" not in message and str(exe) in message
    assert "it is not used" in message and "cannot run g++" in message
    assert not Path(f"{exe}.tampered-ran").exists()


def test_a_native_entry_of_the_layout_before_checksums_is_rebuilt(fake_native, program):
    marker = NativeBackend().compile(program)
    for name in native_build.PROGRAM_ARTEFACTS:
        drop_checksum(Path(marker["cache_dir"]) / name)
    assert not NativeBackend().is_built(program)
    NativeBackend().compile(program)
    assert fake_native.builds == 2 and NativeBackend().is_built(program)


# --------------------------------------------------------------------------- the driver object
@pytest.fixture
def fake_driver_compile(tmp_path, monkeypatch) -> list[list[str]]:
    """driver.cpp "compiled" by writing bytes to the ``-o`` file (no compiler runs)."""
    monkeypatch.setenv("SSMOBS_CACHE", str(tmp_path / "cache"))
    calls: list[list[str]] = []

    def run_compiler(cmd: list[str], what: str) -> object:
        calls.append(cmd)
        Path(cmd[cmd.index("-o") + 1]).write_bytes(b"\x7fELF object " + bytes(range(256)) * 20)
        return type("Done", (), {"stderr": ""})()

    monkeypatch.setattr(native_build, "run_compiler", run_compiler)
    monkeypatch.setattr(native_build, "compiler_version", lambda: "g++ (fake) 0")
    return calls


@pytest.mark.parametrize("damage", list(DAMAGE))
def test_a_damaged_driver_object_is_rebuilt_before_it_is_linked(fake_driver_compile, damage):
    obj = native_build.driver_object()
    good = obj.read_bytes()
    assert native_build.driver_object() == obj and len(fake_driver_compile) == 1
    DAMAGE[damage](obj)
    assert native_build.driver_object() == obj and len(fake_driver_compile) == 2
    assert obj.read_bytes() == good


def test_a_damaged_driver_object_in_a_read_only_cache_is_refused(fake_driver_compile, monkeypatch):
    obj = native_build.driver_object()
    flip_byte(obj)

    def read_only(*args: object, **kwargs: object) -> str:
        raise OSError(errno.EROFS, "Read-only file system", str(obj.parent.parent))

    monkeypatch.setattr(tempfile, "mkdtemp", read_only)
    with pytest.raises(BackendError) as err:
        native_build.driver_object()
    message = str(err.value)
    assert "\n" not in message and str(obj) in message and "cannot be rebuilt" in message
    assert "cannot write the compiled-program cache" in message
    assert len(fake_driver_compile) == 1  # nothing linked from the damaged object


def test_the_precompiled_header_setting_is_zero_or_one(monkeypatch):
    monkeypatch.delenv(native_build.PCH_ENV, raising=False)
    assert native_build.precompiled_header_wanted() is False
    monkeypatch.setenv(native_build.PCH_ENV, "1")
    assert native_build.precompiled_header_wanted() is True
    monkeypatch.setenv(native_build.PCH_ENV, "0")
    assert native_build.precompiled_header_wanted() is False
    monkeypatch.setenv(native_build.PCH_ENV, "yes")
    with pytest.raises(ValueError, match="SSMOBS_STAN_PCH must be 0 or 1"):
        native_build.precompiled_header_wanted()


def test_the_precompiled_header_is_in_no_program_key(monkeypatch):
    """Its object files are the same bytes (tests/stan/test_precompiled_header.py), so the
    setting keys nothing: the same entry with and without it."""
    monkeypatch.setenv(native_build.PCH_ENV, "0")
    off = (native_build.build_key("code"), native_build.driver_key())
    monkeypatch.setenv(native_build.PCH_ENV, "1")
    assert (native_build.build_key("code"), native_build.driver_key()) == off


# --------------------------------------------------------------------------- cmdstanpy
EXE_BYTES = b"\x7fELF" + bytes(range(256)) * 64


@pytest.fixture
def fake_cmdstan(tmp_path, monkeypatch) -> list[Path]:
    cmdstan = tmp_path / "cmdstan-2.99.0"
    (cmdstan / "bin").mkdir(parents=True)
    (cmdstan / "makefile").write_text("CMDSTAN_VERSION := 2.99.0\n")
    monkeypatch.setattr(cmdstanpy, "cmdstan_path", lambda: str(cmdstan))
    monkeypatch.setenv("SSMOBS_CACHE", str(tmp_path / "cache"))
    calls: list[Path] = []

    class Build:
        def __init__(self, stan_file: str | None = None, **_: object) -> None:
            assert stan_file is not None
            calls.append(Path(stan_file))
            exe = Path(stan_file).with_suffix("")
            exe.write_bytes(EXE_BYTES)
            exe.chmod(0o755)
            self.exe_file = str(exe)

    monkeypatch.setattr(cmdstanpy, "CmdStanModel", Build)
    return calls


@pytest.mark.parametrize("damage", list(DAMAGE))
def test_a_damaged_cmdstan_executable_is_rebuilt(fake_cmdstan, program, damage):
    backend = CmdStanPyBackend()
    marker = backend.compile(program)
    assert backend.compile(program) == marker and len(fake_cmdstan) == 1
    DAMAGE[damage](Path(marker["exe_file"]))
    assert backend.compile(program) == marker and len(fake_cmdstan) == 2
    assert Path(marker["exe_file"]).read_bytes() == EXE_BYTES


# --------------------------------------------------------------------------- the LCD kernel
@pytest.fixture(scope="module")
def built_kernel(tmp_path_factory) -> tuple[Path, Path]:
    """The baseline kernel built once (a few seconds), and one with a constant changed by
    1e-6 (a library that loads and gives other bits)."""
    root = tmp_path_factory.mktemp("lcd")
    (root / "good").mkdir()
    (root / "other").mkdir()
    good, _ = lcd_native.build(root / "good")
    source = lcd_native.SOURCE.read_text()
    changed = source.replace("0.57721566490153286061", "0.57721666490153286061", 1)
    assert changed != source, "the kernel lost the constant this test changes"
    (root / "other.cpp").write_text(changed)
    other, _ = lcd_native.build(root / "other", source=root / "other.cpp")
    return good, other


@pytest.fixture
def fake_lcd(built_kernel, tmp_path, monkeypatch) -> list[Path]:
    """The kernel "built" by copying the library built once (same bytes as a real build)."""
    monkeypatch.setenv("SSMOBS_CACHE", str(tmp_path / "cache"))
    monkeypatch.delenv(lcd_native.BUILD_ENV, raising=False)
    builds: list[Path] = []

    def build(directory: Path, flags: tuple[str, ...] = lcd_native.CXXFLAGS, source=None):
        builds.append(directory)
        shutil.copyfile(built_kernel[0], directory / lcd_native.LIB_NAME)
        return directory / lcd_native.LIB_NAME, ["g++", *flags]

    monkeypatch.setattr(lcd_native, "build", build)
    real_cdll = lcd_native.ctypes.CDLL

    def checked_cdll(name: str, *args: object, **kwargs: object) -> object:
        assert io.checksum_problem(name) is None, f"loaded a damaged library {name}"
        return real_cdll(name, *args, **kwargs)

    monkeypatch.setattr(lcd_native.ctypes, "CDLL", checked_cdll)
    lcd_native.kernel_of.cache_clear()
    yield builds
    lcd_native.kernel_of.cache_clear()


def off_the_map(lib: Path, damage: Callable[[Path], None]) -> None:
    """``damage`` done to a copy renamed into place: this process has ``lib`` loaded, and
    writing into a mapped library would crash it (as it would any process using it)."""
    copy = lib.with_name(lib.name + ".copy")
    shutil.copy2(lib, copy)
    if io.checksum_path(lib).is_file():
        shutil.copy2(io.checksum_path(lib), io.checksum_path(copy))
    damage(copy)
    os.replace(copy, lib)
    if io.checksum_path(copy).is_file():
        os.replace(io.checksum_path(copy), io.checksum_path(lib))
    else:
        io.checksum_path(lib).unlink()


def _lcd_entry() -> Path:
    flags = lcd_native.BUILDS["x86-64"]
    return lcd_native.cache_root() / "lcd" / f"kernel-{lcd_native.build_key(flags)}"


@pytest.mark.parametrize("damage", ["flipped-byte", "truncated", "other-constant", "no-checksum"])
def test_a_damaged_lcd_kernel_is_rebuilt_never_loaded(fake_lcd, built_kernel, damage):
    lcd_native.kernel_of("x86-64")
    lib = _lcd_entry() / lcd_native.LIB_NAME
    good = lib.read_bytes()
    assert len(fake_lcd) == 1 and io.checksum_problem(lib) is None
    if damage == "other-constant":
        replace(lib, built_kernel[1].read_bytes())
        assert lib.read_bytes() != good
    else:
        off_the_map(lib, DAMAGE[damage])
    lcd_native.kernel_of.cache_clear()  # another process
    lcd_native.kernel_of("x86-64")
    assert len(fake_lcd) == 2 and lib.read_bytes() == good


def test_a_damaged_lcd_kernel_that_cannot_be_rebuilt_is_refused(fake_lcd, monkeypatch):
    lcd_native.kernel_of("x86-64")
    lib = _lcd_entry() / lcd_native.LIB_NAME
    off_the_map(lib, truncate)

    def no_compiler(*args: object, **kwargs: object) -> None:
        raise lcd_native.LcdKernelUnavailable("the LCD design kernel needs a C++ compiler")

    monkeypatch.setattr(lcd_native, "build", no_compiler)
    lcd_native.kernel_of.cache_clear()
    with pytest.raises(lcd_native.LcdKernelUnavailable) as err:
        lcd_native.kernel_of("x86-64")
    message = str(err.value)
    assert "\n" not in message and str(lib) in message and "not loaded" in message
