"""cmdstanpy backend's program cache, with a fake CmdStan build (no CmdStan needed): the
executable is built in a temporary directory and renamed into place, so a half-written
executable is never taken for a finished build; entries get the umask's mode; a cache
that cannot be written raises BackendError naming the directory."""

from __future__ import annotations

import errno
import os
import stat
from collections.abc import Callable
from pathlib import Path

import cmdstanpy
import pytest
from ssmobs.stan_backends import BackendError
from ssmobs.stan_backends.cmdstanpy import CmdStanPyBackend

pytestmark = pytest.mark.stan

EXE_BYTES = b"\x7fELF" + bytes(range(256)) * 64


class FakeBuild:
    """Stands in for ``cmdstanpy.CmdStanModel(stan_file=...)``: writes the executable
    next to the program in two halves, calling ``between`` after the first."""

    def __init__(self) -> None:
        self.calls: list[Path] = []
        self.between: Callable[[Path], None] | None = None

    def __call__(self, stan_file: str | None = None, exe_file: str | None = None) -> FakeBuild:
        assert stan_file is not None
        src = Path(stan_file)
        self.calls.append(src)
        exe = src.with_suffix("")
        half = len(EXE_BYTES) // 2
        with open(exe, "wb") as fh:
            fh.write(EXE_BYTES[:half])
            fh.flush()
            if self.between is not None:
                self.between(exe)
            fh.write(EXE_BYTES[half:])
        exe.chmod(0o755)
        self.exe_file = str(exe)
        return self


@pytest.fixture
def fake(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> FakeBuild:
    cmdstan = tmp_path / "cmdstan-2.99.0"
    (cmdstan / "bin").mkdir(parents=True)
    (cmdstan / "makefile").write_text("CMDSTAN_VERSION := 2.99.0\n")
    monkeypatch.setattr(cmdstanpy, "cmdstan_path", lambda: str(cmdstan))
    build = FakeBuild()
    monkeypatch.setattr(cmdstanpy, "CmdStanModel", build)
    monkeypatch.setenv("SSMOBS_CACHE", str(tmp_path / "cache"))
    return build


@pytest.fixture
def program(tmp_path: Path) -> Path:
    path = tmp_path / "prog.stan"
    path.write_text("parameters { real y; }\nmodel { y ~ normal(0, 1); }\n")
    return path


def _finished_looking(cache: Path) -> list[Path]:
    """Executables under the final (non-temporary) entry names."""
    return [p / "prog" for p in (cache / "cmdstan").glob("prog-*") if (p / "prog").exists()]


def test_half_written_exe_is_not_a_build(fake, program, tmp_path):
    """While the executable is being written it is not under the entry's final name; a
    build killed half-way leaves nothing a later lookup would take; that lookup builds."""
    cache = tmp_path / "cache"
    seen: list[list[Path]] = []

    def killed(exe: Path) -> None:
        seen.append(_finished_looking(cache))
        raise KeyboardInterrupt  # the job is killed half-way through writing

    fake.between = killed
    with pytest.raises(KeyboardInterrupt):
        CmdStanPyBackend().compile(program)
    assert seen == [[]]
    assert _finished_looking(cache) == []
    fake.between = None
    marker = CmdStanPyBackend().compile(program)
    assert len(fake.calls) == 2  # rebuilt, not the half-written file
    assert Path(marker["exe_file"]).read_bytes() == EXE_BYTES
    assert Path(marker["exe_file"]).parent == Path(marker["cache_dir"])
    # found afterwards without building, and no temporary directories are left
    CmdStanPyBackend().compile(program)
    assert len(fake.calls) == 2
    assert [p.name for p in (cache / "cmdstan").iterdir() if ".tmp-" in p.name] == []


def test_entry_of_the_old_layout_is_rebuilt(fake, program, tmp_path):
    """An entry built in place by an older version (an executable but no build record,
    possibly half-written) is replaced."""
    marker = CmdStanPyBackend().compile(program)
    entry = Path(marker["cache_dir"])
    (entry / "build.json").unlink(missing_ok=True)  # the old layout has none
    Path(marker["exe_file"]).write_bytes(EXE_BYTES[:100])
    again = CmdStanPyBackend().compile(program)
    assert again["exe_file"] == marker["exe_file"]
    assert Path(again["exe_file"]).read_bytes() == EXE_BYTES
    assert len(fake.calls) == 2


def test_entry_mode_follows_the_umask(fake, program):
    old = os.umask(0o002)
    try:
        marker = CmdStanPyBackend().compile(program)
    finally:
        os.umask(old)
    assert stat.S_IMODE(Path(marker["cache_dir"]).stat().st_mode) == 0o775


def test_read_only_cache_names_the_directory(fake, program, tmp_path, monkeypatch):
    cache = tmp_path / "cache"
    real_mkdir = os.mkdir

    def mkdir(path, *args, **kwargs):
        if Path(os.fsdecode(path)).is_relative_to(cache):
            raise OSError(errno.EROFS, os.strerror(errno.EROFS), os.fsdecode(path))
        return real_mkdir(path, *args, **kwargs)

    monkeypatch.setattr(os, "mkdir", mkdir)
    with pytest.raises(BackendError, match=r"(?s)cache .*cmdstan.*SSMOBS_CACHE"):
        CmdStanPyBackend().compile(program)
    assert fake.calls == []
