"""All readers and writers of ssmobs: atomic writes, validated reads.

Every file is written to a temporary name in the target folder and renamed into place,
so a killed job never leaves a file that looks complete (style guide, Sec. 4).  Readers
check what they load and raise :class:`CorruptFileError` naming the file when it is bad.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import os
import re
import tempfile
import threading
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    import pandas

    from .models.base import StateSpaceModel

LOG = logging.getLogger("ssmobs.io")


class CorruptFileError(RuntimeError):
    """An intermediate file exists but cannot be used (truncated, wrong content).

    The message names the file and says how to recover: delete it and rerun, and the
    workflow recomputes it (and everything that depends on it).
    """

    def __str__(self) -> str:
        return f"{self.what} -- delete this file and rerun to recompute it"

    @property
    def what(self) -> str:
        """The file and what is wrong with it, without the remedy: for a warning where the
        file is recomputed at once."""
        return super().__str__()


_UMASK_LOCK = threading.Lock()


def _umask() -> int:
    try:  # Linux >= 4.7 shows it without changing it
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("Umask:"):
                return int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    with _UMASK_LOCK:  # elsewhere os.umask can only be read by setting it
        umask = os.umask(0o022)
        os.umask(umask)
    return umask


def file_mode() -> int:
    """The mode a new regular file gets under the process's umask (0o666 & ~umask)."""
    return 0o666 & ~_umask()


def _temporary_suffix(path: Path, suffix: str | None) -> str:
    return suffix or path.suffix or ".tmp"


def write_error(path: str | os.PathLike, err: OSError) -> OSError:
    """``err`` (raised while writing ``path``) as an OSError whose message names ``path``,
    with the same errno (so the same subclass, e.g. PermissionError for EACCES): a full or
    read-only disk otherwise reports "[Errno 28] No space left on device" and no file."""
    reason = err.strerror or str(err) or type(err).__name__
    message = f"cannot write {path}: {reason}"
    return OSError(err.errno, message) if err.errno is not None else OSError(message)


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path next to ``path``; rename it to ``path`` on success.

    The temporary is ``.<name>.<8 random characters><suffix>`` (see
    :func:`sweep_temporaries`).  Before the rename it gets the mode the umask implies
    (``mkstemp`` creates it 0600, and the mode would survive the rename).  An OSError
    while writing (ENOSPC, EROFS, EACCES, ...) is raised again naming ``path``
    (:func:`write_error`), chained to the original.
    """
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(
            prefix=f".{path.name}.", suffix=_temporary_suffix(path, suffix), dir=path.parent
        )
        os.close(fd)
    except OSError as err:
        raise write_error(path, err) from err
    tmp_path = Path(tmp)
    try:
        try:
            yield tmp_path
            with open(tmp_path, "rb") as fh:
                os.fsync(fh.fileno())
            os.chmod(tmp_path, file_mode())
            os.replace(tmp_path, path)
        except OSError as err:
            raise write_error(path, err) from err
    finally:
        with contextlib.suppress(OSError):  # e.g. the disk became read-only: keep the cause
            tmp_path.unlink(missing_ok=True)


def temporaries(path: str | os.PathLike, suffix: str | None = None) -> list[Path]:
    """Temporaries that :func:`atomic_path` made for ``path`` and that are still there."""
    path = Path(path)
    if not path.parent.is_dir():
        return []
    pattern = re.compile(
        re.escape(f".{path.name}.")
        + r"[A-Za-z0-9_]{8}"
        + re.escape(_temporary_suffix(path, suffix))
        + "$"
    )
    return sorted(p for p in path.parent.iterdir() if pattern.match(p.name) and p.is_file())


def sweep_temporaries(paths: Iterable[str | os.PathLike]) -> list[Path]:
    """Delete what killed writers of ``paths`` left: call at the start of the job that
    writes them (Snakemake runs one job per output at a time, so none is in use).

    Returns the deleted files (each is logged).
    """
    removed = []
    for path in paths:
        for tmp in temporaries(path):
            tmp.unlink(missing_ok=True)
            LOG.info("removed the temporary %s of an interrupted earlier job", tmp)
            removed.append(tmp)
    return removed


@contextlib.contextmanager
def file_lock(path: str | os.PathLike) -> Iterator[None]:
    """Hold an exclusive advisory lock on ``path`` (created if needed) across processes."""
    import fcntl

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "a+") as fh:
        fcntl.flock(fh.fileno(), fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(fh.fileno(), fcntl.LOCK_UN)


def write_text(path: str | os.PathLike, text: str) -> None:
    with atomic_path(path) as tmp:
        tmp.write_text(text)


def file_sha256(path: str | os.PathLike) -> str:
    """SHA-256 of a file's bytes (hex)."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def checksum_path(path: str | os.PathLike) -> Path:
    """The checksum file written beside ``path`` by :func:`write_checksum`."""
    path = Path(path)
    return path.with_name(path.name + ".sha256")


def write_checksum(path: str | os.PathLike) -> None:
    """Write ``<path>.sha256``: lets the workflow see damage that keeps a file's time."""
    write_text(checksum_path(path), file_sha256(path) + "\n")


def checksum_problem(path: str | os.PathLike) -> str | None:
    """Why ``path`` does not match its ``.sha256`` file, or None (also when ``path`` is
    missing: a missing output is Snakemake's business).  A missing checksum is damage: it
    cannot vouch for the file."""
    try:
        actual = file_sha256(path)
    except FileNotFoundError:
        return None
    try:
        expected = checksum_path(path).read_text().strip()
    except FileNotFoundError:
        return f"{path} has no checksum {checksum_path(path).name} (it cannot be trusted)"
    if actual != expected:
        return f"{path} does not match its checksum (damaged or changed after it was written)"
    return None


#: where every workflow job records the checksums of its outputs (:func:`record_checksums`),
#: one file ``<output path>.sha256`` per output, relative to the working directory
CHECKSUM_STORE = Path("results") / "checksums"


def checksum_record(path: str | os.PathLike, store: Path = CHECKSUM_STORE) -> Path:
    """The file of ``store`` that holds the checksum of output ``path``: its path relative
    to the working directory, or for a path outside it, a name made from its absolute path."""
    absolute = os.path.abspath(path)
    relative = os.path.relpath(absolute)
    if relative == ".." or relative.startswith(".." + os.sep) or relative.startswith(str(store)):
        relative = os.path.join("_outside", hashlib.sha256(absolute.encode()).hexdigest()[:32])
    return store / f"{relative}.sha256"


def record_checksums(paths: Iterable[str | os.PathLike], store: Path = CHECKSUM_STORE) -> None:
    """Record the SHA-256 of every existing file of ``paths`` (a job's outputs, once they are
    complete) in ``store``: ``<hash>  <path>`` as ``sha256sum`` writes it, so that damage
    which keeps a file's time is found before a later job reads it (:func:`damaged_files`)."""
    for path in paths:
        if os.path.isfile(path):
            record = checksum_record(path, store)
            inside = record.relative_to(store).parts[0] != "_outside"
            where = os.path.relpath(path) if inside else os.path.abspath(path)
            write_text(record, f"{file_sha256(path)}  {where}\n")


def damaged_files(store: Path = CHECKSUM_STORE) -> list[tuple[Path, str]]:
    """Every file with a checksum record in ``store`` whose bytes no longer match it
    (truncated, edited, damaged on disk; whatever its time), with why.  A recorded file that
    no longer exists is no damage (Snakemake makes a missing output); a record that cannot
    be read is ignored (its file is then unchecked, as one made before records existed)."""
    found: list[tuple[Path, str]] = []
    if not store.is_dir():
        return found
    for folder, _, names in os.walk(store):
        for name in sorted(names):
            if not name.endswith(".sha256"):
                continue
            try:
                expected, _, where = (Path(folder) / name).read_text().rstrip("\n").partition("  ")
            except (OSError, UnicodeDecodeError):
                continue
            path = Path(where)
            if (
                not where
                or not path.is_file()
                or checksum_record(path, store) != Path(folder) / name
            ):
                continue
            size = path.stat().st_size
            if file_sha256(path) != expected:
                what = "is empty" if size == 0 else "does not match the checksum its job recorded"
                found.append((path, f"{path} {what} (damaged or changed after it was written)"))
    return sorted(found)


def json_default(obj: Any) -> Any:
    """JSON form of NumPy scalars and arrays and of paths (for ``json.dumps(default=...)``)."""
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"cannot write {type(obj).__name__} to JSON")


def write_json(path: str | os.PathLike, obj: Any) -> None:
    """Write JSON atomically (sorted keys, so reruns give identical bytes)."""
    write_text(
        path, json.dumps(obj, indent=1, sort_keys=True, default=json_default, allow_nan=True) + "\n"
    )


def read_json(path: str | os.PathLike, required: Sequence[str] = ()) -> Any:
    """Read JSON; CorruptFileError naming the file if it does not parse or lacks keys."""
    path = Path(path)
    try:
        obj = json.loads(path.read_text())
    except (OSError, ValueError) as err:
        raise CorruptFileError(f"{path}: not valid JSON ({err})") from err
    missing = [k for k in required if not isinstance(obj, dict) or k not in obj]
    if missing:
        raise CorruptFileError(f"{path}: missing keys {missing}")
    return obj


#: the key of a checked JSON file (:func:`write_checked_json`) that holds its checksum
CONTENT_CHECKSUM = "content_sha256"


def _content_checksum(obj: dict[str, Any]) -> str:
    text = json.dumps(obj, sort_keys=True, default=json_default, allow_nan=True)
    return hashlib.sha256(text.encode()).hexdigest()


def write_checked_json(path: str | os.PathLike, obj: dict[str, Any]) -> None:
    """Write the mapping ``obj`` as JSON with the checksum of its content
    (:data:`CONTENT_CHECKSUM`): a cache file that later jobs read (a point of the choice of
    K, a cell of a map), so that an edit that keeps the file's time is found."""
    plain = json.loads(json.dumps(obj, default=json_default, allow_nan=True))
    write_json(path, {**plain, CONTENT_CHECKSUM: _content_checksum(plain)})


def read_checked_json(path: str | os.PathLike, required: Sequence[str] = ()) -> dict[str, Any]:
    """A mapping written by :func:`write_checked_json`, without its checksum;
    CorruptFileError naming the file when it does not parse, lacks keys, or its checksum
    is missing or does not match its content."""
    obj = read_json(path, required=[*required, CONTENT_CHECKSUM])
    expected = obj.pop(CONTENT_CHECKSUM)
    if expected != _content_checksum(obj):
        raise CorruptFileError(f"{path}: its checksum does not match (damaged or edited)")
    return obj


@dataclass(frozen=True)
class NetcdfData:
    """A NetCDF file's variables (name -> values), their dimension names and its global
    attributes, read without xarray (whose import costs each job about half a second)."""

    variables: dict[str, np.ndarray]
    dims: dict[str, tuple[str, ...]]
    attrs: dict[str, Any]

    def __getitem__(self, name: str) -> np.ndarray:
        return self.variables[name]


def write_netcdf(
    path: str | os.PathLike,
    variables: Mapping[str, tuple[tuple[str, ...], np.ndarray]],
    attrs: Mapping[str, Any],
) -> None:
    """Write ``variables`` (name -> (dimension names, values)) and the global ``attrs`` as
    NetCDF-4 with h5netcdf, atomically.  A variable named like one of its dimensions is that
    dimension's coordinate; text becomes variable-length strings (as xarray writes them)."""
    import h5netcdf
    import h5py

    arrays = {name: (tuple(dims), np.asarray(values)) for name, (dims, values) in variables.items()}
    sizes: dict[str, int] = {}
    for name, (dims, values) in arrays.items():
        if len(dims) != values.ndim:
            raise ValueError(
                f"variable {name}: {len(dims)} dimension names for {values.ndim}-d values"
            )
        for dim, n in zip(dims, values.shape, strict=True):
            if sizes.setdefault(dim, n) != n:
                raise ValueError(f"dimension {dim}: length {n} in {name}, {sizes[dim]} before")
    coordinates = [name for name, (dims, _) in arrays.items() if dims == (name,)]
    with atomic_path(path, suffix=".nc") as tmp, h5netcdf.File(tmp, "w") as f:
        f.dimensions = sizes
        for name in [*coordinates, *(n for n in arrays if n not in coordinates)]:
            dims, values = arrays[name]
            if values.dtype.kind == "U":
                f.create_variable(name, dims, dtype=h5py.string_dtype(), data=values.astype(object))
            else:
                f.create_variable(name, dims, data=values)
        f.attrs.update(attrs)


def read_netcdf(path: str | os.PathLike, required_vars: Sequence[str] = ()) -> NetcdfData:
    """Load a NetCDF file fully into memory; CorruptFileError naming the file if unreadable."""
    import h5netcdf

    path = Path(path)
    try:
        with h5netcdf.File(path, "r") as f:
            variables = {name: _loaded(var[...]) for name, var in f.variables.items()}
            dims = {name: tuple(var.dimensions) for name, var in f.variables.items()}
            attrs = dict(f.attrs)
    except Exception as err:  # h5py raises several types for damaged files
        raise CorruptFileError(f"{path}: not a readable NetCDF file ({err})") from err
    missing = [v for v in required_vars if v not in variables]
    if missing:
        raise CorruptFileError(f"{path}: missing variables {missing}")
    return NetcdfData(variables=variables, dims=dims, attrs=attrs)


def _loaded(values: Any) -> np.ndarray:
    """Variable-length strings (read as Python strings) as a NumPy text array, other
    values as read."""
    values = np.asarray(values)
    return values.astype(str) if values.dtype.kind == "O" else values


def write_parquet(path: str | os.PathLike, frame: pandas.DataFrame) -> None:
    with atomic_path(path, suffix=".parquet") as tmp:
        frame.to_parquet(tmp, index=False)


def read_parquet(path: str | os.PathLike, required_columns: Sequence[str] = ()) -> pandas.DataFrame:
    import pandas as pd

    path = Path(path)
    try:
        frame = pd.read_parquet(path)
    except Exception as err:
        raise CorruptFileError(f"{path}: not a readable Parquet file ({err})") from err
    missing = [c for c in required_columns if c not in frame.columns]
    if missing:
        raise CorruptFileError(f"{path}: missing columns {missing}")
    return frame


def array_checksum(*arrays: np.ndarray) -> str:
    """SHA-256 of the arrays' bytes (dtype and shape included): stored beside cached arrays."""
    h = hashlib.sha256()
    for a in arrays:
        a = np.ascontiguousarray(a)
        h.update(str(a.dtype).encode())
        h.update(str(a.shape).encode())
        h.update(a.tobytes())
    return h.hexdigest()


# ---------------------------------------------------------------- joint MAP (Sec. III.B)
def write_joint_map(
    path: str | os.PathLike, result: Any, model: StateSpaceModel, T: int, attrs: dict
) -> None:
    """Full Theta_hat and local variances of every k of a
    :class:`~ssmobs.joint_map.driver.JointMapResult`, labelled (dimensions ``k`` and
    ``component`` = ``model.theta_names(T)``)."""
    variables = {
        "k": (("k",), np.arange(result.theta_hat.shape[0])),
        "component": (("component",), np.asarray(model.theta_names(T), dtype=str)),
        "theta_hat": (("k", "component"), result.theta_hat),
        "local_variance": (("k", "component"), result.local_variance),
        "status": (("k",), np.asarray(result.status, dtype=str)),
    }
    write_netcdf(path, variables, attrs)


# ---------------------------------------------------------------- design disturbances
def write_disturbances(path: str | os.PathLike, result: Any) -> None:
    """Store a :class:`~ssmobs.design.disturbances.DesignResult` as the paper's (q x K) matrix."""
    matrix = np.asarray(result.matrix, dtype=float)
    write_netcdf(
        path,
        {
            "component": (("component",), np.arange(matrix.shape[0])),
            "k": (("k",), np.arange(matrix.shape[1])),
            "disturbance": (("component", "k"), matrix),
        },
        {
            "method": result.method,
            "q": int(result.q),
            "K": int(result.K),
            "seed": int(result.seed),
            "b_max": float(result.b_max) if result.b_max is not None else float("nan"),
            "distance_raw": float(result.distance_raw),
            "distance": float(result.distance),
            "iterations": int(result.iterations),
            "covariance_correction": result.covariance_correction,
            "checksum": array_checksum(matrix),
            "description": "design disturbance vectors (columns), state disturbances first "
            "(Hanebeck & Czado, Sec. III.A)",
        },
    )


def read_disturbances(
    path: str | os.PathLike, q: int | None = None, K: int | None = None
) -> tuple[np.ndarray, dict]:
    """Load a disturbance matrix (q x K) and its attributes; CorruptFileError if damaged."""
    ds = read_netcdf(path, required_vars=["disturbance"])
    matrix = np.asarray(ds["disturbance"], dtype=float)
    attrs = dict(ds.attrs)
    if attrs.get("checksum") != array_checksum(matrix):
        raise CorruptFileError(f"{path}: checksum mismatch (file damaged or edited)")
    if (q is not None and matrix.shape[0] != q) or (K is not None and matrix.shape[1] != K):
        raise CorruptFileError(f"{path}: expected a {q} x {K} matrix, found {matrix.shape}")
    return matrix, attrs
