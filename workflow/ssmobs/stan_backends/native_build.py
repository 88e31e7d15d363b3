"""Building the native backend's programs (:mod:`.native`): the toolchain and the cache entries.

Compiling
    :meth:`.native.NativeBackend.compile` runs ``stanc`` and ``g++`` once per :func:`build_key`
    into ``<cache_root>/native/<slug>-<key>/`` (:mod:`.cache`), under an exclusive lock, in a
    temporary directory renamed into place when complete.  The driver is compiled once into
    an object file of its own (:func:`driver_object`, ``<cache_root>/native/driver-<key>/``)
    and linked with each program's object file, so a program costs one compile of the
    stanc-generated C++ only (as CmdStan's ``main.o``).  Both compiles see our headers in
    :data:`SHADOW_INCLUDE_DIR` before httpstan's (Stan's ``stan/model/gradient.hpp``
    replaced by one that reuses a message stream per thread; the wheel is not changed).  A
    stanc or compiler error raises RuntimeError with the tool's own message; nothing is
    written into the repository.

Cached programs are self-contained
    An entry holds the executable ``driver``, the shared libraries it needs from the wheel
    (:data:`RUNTIME_LIBS`, i.e. TBB) copied beside it, and ``build.json`` (key, compiler
    version, command).  The executable's RUNPATH is ``$ORIGIN`` only, so it finds the
    copies wherever the entry is and whether or not the environment that built it still
    exists; at run time it needs only the system's C and C++ runtime (glibc, libstdc++ at
    least as new as the building compiler's, libgcc_s, libm).  Looking a program up runs
    ``stanc --version`` from the wheel but never the C++ compiler, so a node without g++
    uses programs built elsewhere (see :func:`build_key`).

Checksums
    The executable, the libraries beside it and the driver's object file carry checksums
    written at build time and verified before each use (:mod:`.cache`): a damaged or
    replaced file is rebuilt, never run or linked.

A precompiled header (opt-in)
    With ``SSMOBS_STAN_PCH=1`` in the environment (:data:`PCH_ENV`) a program's object file
    is compiled with a precompiled ``stan/model/model_header.hpp`` (:func:`precompiled_header`,
    built once per compiler and flags into ``<cache_root>/native/pch-<key>/``, 770 MiB): 13.5
    instead of 21.7 CPU-s for the analytic Same program (docs/performance.md), and the same
    executable byte for byte (GCC's precompiled header is the parsed text of the same header;
    tests/stan/test_precompiled_header.py compares them), so the setting is not in any key and
    is recorded in ``build.json`` only.  A header the compiler refuses (``-Winvalid-pch``) is
    read as text instead.

The same bytes from every build
    stanc runs in the build directory on relative names and names the program's file in
    messages, and GCC maps the source directories to fixed names (:func:`path_maps`): an
    executable's bytes depend on neither the temporary directory nor the environment's path.
"""

from __future__ import annotations

import logging
import os
import re
import shutil
import subprocess
import time
from functools import lru_cache
from pathlib import Path

from .base import BackendError, log_captured
from .cache import (
    cache_root,
    content_key,
    ensure_entry,
    new_build_dir,
    publish_entry,
    shared_mode,
    tail,
)
from .native_run import EXIT_USAGE

LOG = logging.getLogger("ssmobs.stan")

#: the driver's C++ source
DRIVER_SOURCE = Path(__file__).resolve().parent / "native_driver" / "driver.cpp"
#: headers of ours that stand in for Stan's under the same names (``stan/model/gradient.hpp``:
#: one message stream per thread instead of one per gradient call); on the include path
#: before httpstan's for the driver and every program, and keyed (:func:`shadow_key`)
SHADOW_INCLUDE_DIR = Path(__file__).resolve().parent / "native_include"
#: preprocessor definitions httpstan builds its models with (same numerics as PyStan)
DEFINES: tuple[str, ...] = (
    "BOOST_DISABLE_ASSERTS",
    "BOOST_PHOENIX_NO_VARIADIC_EXPRESSION",
    "STAN_THREADS",
    "_REENTRANT",
    "_GLIBCXX_USE_CXX11_ABI=0",
)
#: compiler flags (optimisation as httpstan's; C++17 for the driver)
CXXFLAGS: tuple[str, ...] = (
    "-O3",
    "-std=c++17",
    "-Wno-sign-compare",
    "-Wno-ignored-attributes",
    "-Wno-deprecated-declarations",
)
#: linker flags: the executable finds its libraries beside itself, wherever the entry is
LDFLAGS: tuple[str, ...] = ("-Wl,--enable-new-dtags", "-Wl,-rpath,$ORIGIN")
#: extra flags of a program with a user header (generated C++ of ours): no contraction of
#: a * b + c into fused multiply-adds, whatever the compiler's default
USER_HEADER_FLAGS: tuple[str, ...] = ("-ffp-contract=off",)
#: shared libraries of the wheel's ``lib/`` the executable needs (copied into the entry)
RUNTIME_LIBS: tuple[str, ...] = ("libtbb.so.2",)
#: the executable's name in a cache entry
EXE_NAME = "driver"
#: the driver's object file in its own cache entry (:func:`driver_object`)
DRIVER_OBJECT = "driver.o"
#: the compiled files of a program's entry, each with its checksum
PROGRAM_ARTEFACTS: tuple[str, ...] = (EXE_NAME, *RUNTIME_LIBS)
#: environment variable that turns the precompiled Stan header on (``1``) or off (``0``,
#: unset: the default); read by the build only, see the module docstring
PCH_ENV = "SSMOBS_STAN_PCH"
#: the header a precompiled header entry holds (it includes Stan's model header), and its
#: compiled form beside it, where GCC looks for it
PCH_HEADER = "stan_model_header.hpp"
PCH_FILE = PCH_HEADER + ".gch"


@lru_cache(maxsize=1)
def httpstan_dir() -> Path:
    """The installed httpstan package directory (stanc, include/, lib/)."""
    try:
        import httpstan
    except ImportError as err:  # pragma: no cover - httpstan is a dependency
        raise BackendError(
            "the native backend needs the httpstan wheel (pip install "
            "httpstan): it ships stanc, the Stan sources and TBB"
        ) from err
    return Path(httpstan.__file__).resolve().parent


def _tool_version(cmd: list[str]) -> str:
    try:
        out = subprocess.run(cmd, capture_output=True, text=True, timeout=60)
    except (OSError, subprocess.TimeoutExpired) as err:
        raise BackendError(f"cannot run {cmd[0]}: {err}") from err
    if out.returncode != 0:
        raise BackendError(f"{' '.join(cmd)} failed: {tail(out.stderr or out.stdout)}")
    return (out.stdout or out.stderr).strip().splitlines()[0]


@lru_cache(maxsize=1)
def stan_version() -> str:
    """stanc's version line, e.g. ``stanc3 v2.35.0 (Unix)``."""
    return _tool_version([str(httpstan_dir() / "stanc"), "--version"])


@lru_cache(maxsize=1)
def httpstan_version() -> str:
    """The httpstan wheel's version (its Stan Math, TBB and headers), read, not run."""
    import httpstan

    return str(getattr(httpstan, "__version__", "unknown"))


def compiler() -> str:
    """The C++ compiler (``$CXX``, default g++)."""
    return os.environ.get("CXX", "g++")


def compiler_version() -> str:
    """The compiler's version line (runs it: only when building)."""
    return _tool_version([compiler(), "--version"])


def shadow_headers() -> dict[str, str]:
    """Relative path -> text of every header in :data:`SHADOW_INCLUDE_DIR`."""
    root = SHADOW_INCLUDE_DIR
    return {
        p.relative_to(root).as_posix(): p.read_text()
        for p in sorted(root.rglob("*.hpp"))
        if p.is_file()
    }


def shadow_key() -> dict[str, str]:
    """``{"shadow_headers": <hash>}`` of the headers that stand in for Stan's; empty without
    any, so that the keys of entries built without them stay."""
    headers = shadow_headers()
    return {"shadow_headers": content_key(headers)} if headers else {}


def build_key(code: str, user_header: str | None = None) -> dict[str, str]:
    """What determines the executable; its hash names the cache directory.

    Program text, driver source, Stan version (``stanc --version`` of the wheel, which is
    present wherever this package runs), httpstan version, compiler and linker flags and
    the entry's layout (and that its messages name the program's file).  Deliberately *not*
    the C++ compiler, neither its version nor its
    path: the version can only be had by running the compiler and the path only by
    finding it on PATH, and a lookup must work where there is no compiler (a cluster node
    using programs built on the login node), which a key the node cannot compute would
    defeat.  A finished program does not depend on the compiler still being there (it is
    self-contained, see the module docstring), and programs built by different compilers
    from the same sources run the same Stan service with IEEE arithmetic (no
    ``-ffast-math``); the records are keyed by backend and Stan version, not by the
    compiler, in any case.  The compiler's command, path and version are recorded in the
    entry's ``build.json`` (and in the marker) instead; to rebuild with another compiler,
    delete the cache.

    ``user_header``: the text of a C++ header that defines the program's external functions
    (``stanc --allow-undefined``, included before the generated model), keyed as well;
    absent without one, so the keys of the stock programs stay.  The headers of ours that
    stand in for Stan's (:func:`shadow_key`) are keyed too: both object files include them.
    """
    extra = (
        {}
        if user_header is None
        else {
            "user_header": content_key({"code": user_header}),
            "user_header_flags": " ".join(USER_HEADER_FLAGS),
        }
    )
    return {
        **extra,
        **shadow_key(),
        "program": content_key({"code": code}),
        "objects": "driver.o + model.o",
        "driver": content_key({"code": DRIVER_SOURCE.read_text()}),
        "stan": stan_version(),
        "httpstan": httpstan_version(),
        "flags": " ".join(CXXFLAGS + tuple("-D" + d for d in DEFINES) + LDFLAGS),
        "path_maps": PATH_MAPS_KEY,
        "runtime_libs": ",".join(RUNTIME_LIBS),
        # the executable's messages name the program's file (stanc --filename-in-msg);
        # entries built before named their temporary build directory
        "messages": "--filename-in-msg, stanc run in the build directory",
    }


def run_compiler(cmd: list[str], what: str) -> subprocess.CompletedProcess:
    """Run the C++ compiler; RuntimeError with its error lines when it fails or cannot run."""
    try:
        out = subprocess.run(cmd, capture_output=True, text=True)
    except OSError as err:
        raise RuntimeError(
            f"compiling {what} failed: cannot run the C++ compiler {compiler()!r}: {err}"
        ) from err
    if out.returncode != 0:
        errors = [ln for ln in out.stderr.splitlines() if "error" in ln]
        raise RuntimeError(
            f"compiling {what} failed ({compiler()} exit {out.returncode}):\n"
            + "\n".join(errors[:20] or [tail(out.stderr)])
        )
    return out


#: what the compiled files' messages (``__FILE__`` in Eigen's and Stan's checks) call the
#: directories the sources lie in (:func:`path_maps`); keyed, as the bytes follow it
PATH_MAPS_KEY = "-fmacro-prefix-map: httpstan/include ssmobs/native_include ssmobs/native_driver ."


def path_maps(*build_dirs: Path) -> list[str]:
    """GCC's ``-fmacro-prefix-map`` for httpstan's headers, ours and the driver's source
    (without ``build_dirs``), or for ``build_dirs`` (a program's temporary build directory,
    its user header's) as ``.``: the bytes of a build then depend neither on the
    environment's path nor on where it was built, so two builds of one program are the
    same file."""
    fixed = [
        (httpstan_dir() / "include", "httpstan/include"),
        (SHADOW_INCLUDE_DIR, "ssmobs/native_include"),
        (DRIVER_SOURCE.parent, "ssmobs/native_driver"),
    ]
    maps = [(d, ".") for d in build_dirs] if build_dirs else fixed
    return [f"-fmacro-prefix-map={src}={dst}" for src, dst in maps]


def compile_flags() -> list[str]:
    """The C++ compiler's flags for the driver and the programs: our headers that stand in
    for Stan's (:data:`SHADOW_INCLUDE_DIR`) first on the include path, then httpstan's, and
    the directories' names in messages (:func:`path_maps`)."""
    return [
        *CXXFLAGS,
        *("-D" + d for d in DEFINES),
        f"-I{SHADOW_INCLUDE_DIR}",
        f"-I{httpstan_dir() / 'include'}",
        *path_maps(),
    ]


def driver_key() -> dict[str, str]:
    """What determines ``driver.o``: the driver's source, the headers standing in for
    Stan's, the Stan version and the flags."""
    return {
        **shadow_key(),
        "driver": content_key({"code": DRIVER_SOURCE.read_text()}),
        "stan": stan_version(),
        "httpstan": httpstan_version(),
        "flags": " ".join(CXXFLAGS + tuple("-D" + d for d in DEFINES)),
        "path_maps": PATH_MAPS_KEY,
    }


def driver_object() -> Path:
    """The driver compiled once into ``driver.o`` (cached, keyed by :func:`driver_key`);
    every program's executable links it."""
    parts = driver_key()
    cache_dir = cache_root() / "native" / f"driver-{content_key(parts)}"

    def build() -> None:
        work = new_build_dir(cache_dir)
        try:
            t0 = time.perf_counter()
            LOG.info("compiling the native driver once into %s", cache_dir)
            cmd = [compiler(), *compile_flags(), "-c", str(DRIVER_SOURCE)]
            cmd += ["-o", str(work / DRIVER_OBJECT)]
            cxx_version = compiler_version()
            log_captured("compiler for driver.cpp", run_compiler(cmd, "driver.cpp").stderr)
            record = {**parts, "compiler_version": cxx_version}
            publish_entry(work, cache_dir, record, (DRIVER_OBJECT,))
            LOG.info("compiled the native driver in %.1f s", time.perf_counter() - t0)
        finally:
            shutil.rmtree(work, ignore_errors=True)

    ensure_entry(cache_dir, (DRIVER_OBJECT,), build)
    return cache_dir / DRIVER_OBJECT


def precompiled_header_wanted() -> bool:
    """Whether :data:`PCH_ENV` asks for the precompiled header (``1``; ``0`` or unset: no).
    ValueError (one line) for any other value."""
    value = os.environ.get(PCH_ENV, "0").strip() or "0"
    if value not in ("0", "1"):
        raise ValueError(f"{PCH_ENV} must be 0 or 1 (the precompiled Stan header); got {value!r}")
    return value == "1"


def precompiled_header(extra_flags: tuple[str, ...] = ()) -> Path:
    """The precompiled ``stan/model/model_header.hpp`` for the programs' flags plus
    ``extra_flags`` (cached, keyed by the flags, the headers standing in for Stan's, the Stan
    and httpstan versions and the compiler's version line, since a ``.gch`` is valid for one
    compiler only); returns the header to pass with ``-include`` (its ``.gch`` beside it)."""
    cxx_version = compiler_version()
    flags = [*compile_flags(), *extra_flags]
    parts = {
        **shadow_key(),
        "stan": stan_version(),
        "httpstan": httpstan_version(),
        "flags": " ".join(CXXFLAGS + tuple("-D" + d for d in DEFINES) + extra_flags),
        "path_maps": PATH_MAPS_KEY,
        "compiler_version": cxx_version,
    }
    cache_dir = cache_root() / "native" / f"pch-{content_key(parts)}"

    def build() -> None:
        work = new_build_dir(cache_dir)
        try:
            t0 = time.perf_counter()
            LOG.info("precompiling Stan's model header once into %s", cache_dir)
            (work / PCH_HEADER).write_text("#include <stan/model/model_header.hpp>\n")
            cmd = [compiler(), *flags, "-x", "c++-header", str(work / PCH_HEADER)]
            cmd += ["-o", str(work / PCH_FILE)]
            log_captured(
                "compiler for the precompiled header", run_compiler(cmd, PCH_HEADER).stderr
            )
            record = {**parts, "compiler_path": shutil.which(compiler()), "command": cmd}
            publish_entry(work, cache_dir, record, (PCH_HEADER, PCH_FILE))
            LOG.info("precompiled Stan's model header in %.1f s", time.perf_counter() - t0)
        finally:
            shutil.rmtree(work, ignore_errors=True)

    ensure_entry(cache_dir, (PCH_HEADER, PCH_FILE), build)
    return cache_dir / PCH_HEADER


def check_self_contained(exe: Path) -> None:
    """Start the new executable without ``LD_LIBRARY_PATH`` (it must stop at its usage
    check): BackendError when the loader cannot find a library beside it."""
    env = {k: v for k, v in os.environ.items() if k != "LD_LIBRARY_PATH"}
    try:
        out = subprocess.run([str(exe)], capture_output=True, text=True, env=env, timeout=60)
    except (OSError, subprocess.TimeoutExpired) as err:
        raise BackendError(f"the new native driver {exe} does not start: {err}") from err
    if out.returncode != EXIT_USAGE:
        raise BackendError(
            f"the new native driver {exe} does not start on its own (exit code "
            f"{out.returncode}):\n{tail(out.stderr or out.stdout)}"
        )


def build_program(
    path: Path,
    code: str,
    cache_dir: Path,
    parts: dict[str, str],
    user_header: Path | None = None,
) -> None:
    """stanc + g++ into a temporary sibling directory, with the wheel's runtime
    libraries copied beside the executable, renamed to ``cache_dir``.  ``user_header``:
    a C++ header defining the program's external functions (``stanc --allow-undefined``,
    force-included before the generated model, as CmdStan's ``USER_HEADER``)."""
    work = new_build_dir(cache_dir)
    try:
        t0 = time.perf_counter()
        LOG.info(
            "compiling %s with the native backend (%s) into %s",
            path.name,
            parts["stan"],
            cache_dir,
        )
        hdir = httpstan_dir()
        model_name = re.sub(r"\W", "_", path.stem) + "_model"
        (work / "program.stan").write_text(code)
        stanc = subprocess.run(
            [
                str(hdir / "stanc"),
                "--name",
                model_name,
                # messages name the program's file, and stanc runs in the build directory
                # on relative names (it writes its command line into the C++), so that two
                # builds of one program give the same bytes wherever they are built
                "--filename-in-msg",
                path.name,
                *(["--allow-undefined"] if user_header is not None else []),
                "--o",
                "model.hpp",
                "program.stan",
            ],
            capture_output=True,
            text=True,
            cwd=work,
        )
        if stanc.returncode != 0:
            msg = (stanc.stderr or stanc.stdout).replace(path.name, str(path))
            raise RuntimeError(f"stanc rejected {path}:\n{msg.strip()}")
        log_captured(f"stanc warnings for {path.name}", stanc.stderr)
        cxx_version = compiler_version()  # BackendError when there is no compiler
        driver_o = driver_object()
        exe = work / EXE_NAME
        extra = USER_HEADER_FLAGS if user_header is not None else ()
        dirs = (work,) if user_header is None else (work, user_header.parent)
        model_cmd = [compiler(), *compile_flags(), *path_maps(*dirs), *extra]
        model_cmd += ["-x", "c++", "-c"]
        pch = precompiled_header(extra) if precompiled_header_wanted() else None
        if pch is not None:  # the first include, so that GCC takes the .gch
            model_cmd += ["-Winvalid-pch", "-include", str(pch)]
        if user_header is not None:
            model_cmd += ["-include", str(user_header)]
        model_cmd += [str(work / "model.hpp"), "-o", str(work / "model.o")]
        log_captured(f"compiler for {path.name}", run_compiler(model_cmd, str(path)).stderr)
        link_cmd = [compiler(), str(driver_o), str(work / "model.o"), "-o", str(exe)]
        link_cmd += [f"-L{hdir / 'lib'}", "-ltbb", *LDFLAGS]
        log_captured(f"linker for {path.name}", run_compiler(link_cmd, str(path)).stderr)
        (work / "model.o").unlink()
        for lib in RUNTIME_LIBS:
            shutil.copyfile(hdir / "lib" / lib, work / lib)
            (work / lib).chmod(shared_mode())
        check_self_contained(exe)
        (work / "program.stan").unlink()
        publish_entry(
            work,
            cache_dir,
            {
                **parts,
                "compiler_version": cxx_version,
                "compiler_path": shutil.which(compiler()),
                "stan_file": str(path),
                "precompiled_header": None if pch is None else str(pch),
                "command": [model_cmd, link_cmd],
            },
            PROGRAM_ARTEFACTS,
        )
        LOG.info("compiled %s in %.1f s", path.name, time.perf_counter() - t0)
    finally:
        shutil.rmtree(work, ignore_errors=True)
