"""The Stan stage's record cache: keys, hashes, paths and reading records back.

Every trajectory k of the NUTS stage (:mod:`ssmobs.nuts.batch`; the record format:
:mod:`ssmobs.nuts.record_format`) is stored as ``records_dir/k{k:05d}.json``.  A rerun reuses a
record only when its key matches (:func:`record_key`): scenario, k, seed, Stan seed, the
Stan program's hash (:func:`program_hash`), the hash of every setting that determines the record
(:func:`settings_hash`: sampler, the diagnostics' implementation, init, prior bounds, true
values, the KDE estimator; not the convergence thresholds, which the tables apply), the
backend with its Stan version (:func:`backend_identity`) and the data's checksum.  The
records folder itself is keyed by the code that makes records (:mod:`ssmobs.cache_keys`).
Kept draws go to ``draws_dir/k{k:05d}.nc`` (:func:`draws_path`).

A batch table of the Stan stage is checked against the records it was built from: cheaply
before every DAG build (:func:`changed_batch_records`, which the workflow's repair of damaged
batches calls) and fully by gather_nuts (:func:`check_batch_records`).
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
from collections.abc import Iterable
from dataclasses import asdict
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from .. import io, seeds
from ..stan_backends.base import program_digest, sampler_key
from .marginal_map import GRID_PER_BW

if TYPE_CHECKING:
    import pandas

    from ..models.base import PriorBounds, StateSpaceModel
    from ..stan_backends.base import SamplerSettings
    from .convergence import ConvergenceSettings

LOG = logging.getLogger("ssmobs.nuts")

#: version of the record format; records of another version are recomputed
#: (2: keyed without the convergence thresholds, which the tables apply to the stored
#: diagnostics; R-hat and ESS per block of Theta; the checksum of kept draws;
#: 3: the record's own checksum, :data:`RECORD_CHECKSUM`)
RECORD_VERSION = 3
#: the field of a record holding the SHA-256 of the rest of it (:func:`write_record`)
RECORD_CHECKSUM = "record_sha256"
#: keys every record has (checked when a record is read back)
RECORD_KEYS = (
    "record_version",
    "key",
    "k",
    "status",
    "converged",
    "failed_checks",
    "reason",
    "diagnostics",
    "theta_names",
    "map",
    "q5",
    "q95",
)
#: the KDE/quantile method, part of the settings hash (change it when the estimator changes)
ESTIMATOR = {
    "kde": "gaussian, silverman bw, linear binning + fft",
    "grid_per_bw": GRID_PER_BW,
    "quantile": "type 7",
    "mode": "argmax + parabolic refinement",
}


# --------------------------------------------------------------------------- keys
def _floats(values: Any) -> list[float]:
    """A 1-d array (or scalar) as a list of Python floats, as it enters the hashes."""
    return np.atleast_1d(np.asarray(values, dtype=float)).ravel().tolist()


def _sha(obj: Any) -> str:
    text = json.dumps(obj, sort_keys=True, separators=(",", ":"), default=io.json_default)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def program_hash(stan_file: str | Path, user_header: str | Path | None = None) -> str:
    """SHA-256 (16 hex digits) of the Stan program's text with its ``#include`` files, and
    with the C++ header of its external functions when it has one."""
    if user_header is None:
        return program_digest(stan_file)
    return _sha(
        {"program": program_digest(stan_file), "user_header": Path(user_header).read_text()}
    )


def settings_hash(
    model: StateSpaceModel,
    T: int,
    sampler: SamplerSettings,
    convergence: ConvergenceSettings,
    init: str,
    bounds: PriorBounds,
    omega_true: np.ndarray,
    x0_true: np.ndarray,
) -> str:
    """Hash of everything besides (scenario, k, seed, program, data) that determines a record.

    ``omega_true`` in the model's parameter order and ``x0_true`` are arrays (as a
    :class:`~ssmobs.config.scenario.Scenario` holds them); ``sampler.workers`` is left out: it
    changes how chains are scheduled, not the draws.
    """
    sampler_d = sampler_key({k: v for k, v in asdict(sampler).items() if k != "workers"})
    payload = {
        "record_version": RECORD_VERSION,
        "model": model.slug,
        "T": int(T),
        "sampler": sampler_d,
        # the thresholds change no record: tables apply them (convergence.apply_thresholds)
        "diagnostics": convergence.implementation,
        "init": init,
        "bounds": {
            "lower": np.asarray(bounds.lower, float).tolist(),
            "upper": np.asarray(bounds.upper, float).tolist(),
        },
        "omega_true": _floats(omega_true),
        "x0_true": _floats(x0_true),
        "estimator": ESTIMATOR,
    }
    return _sha(payload)


def backend_identity(backend: Any) -> str:
    """``"<backend> <Stan version>"``: records of another backend or Stan are not reused."""
    ident = (
        backend.identity()
        if hasattr(backend, "identity")
        else {"backend": getattr(backend, "name", type(backend).__name__)}
    )
    return " ".join(str(ident[k]) for k in sorted(ident))


def record_key(
    scenario: str,
    k: int,
    seed: int,
    prog_hash: str,
    set_hash: str,
    z_k: np.ndarray,
    x_k: np.ndarray,
    backend: str = "",
    *,
    stan_seed: int | None = None,
    init_point: tuple[np.ndarray, ...] | None = None,
) -> dict[str, Any]:
    """The key a stored record must match to be reused; ``stan_seed``: one Stan seed for
    every trajectory (scenario key ``stan_seed``), else one derived per trajectory;
    ``init_point``: the (Omega, x0, x) the chains start from (init "joint_map")."""
    key = {
        "scenario": scenario,
        "k": int(k),
        "seed": int(seed),
        "stan_seed": (
            seeds.int_seed(seed, "nuts", scenario, int(k)) if stan_seed is None else int(stan_seed)
        ),
        "program_hash": prog_hash,
        "settings_hash": set_hash,
        "backend": backend,
        "data_hash": io.array_checksum(np.asarray(z_k, float), np.asarray(x_k, float))[:16],
    }
    if init_point is not None:  # absent otherwise, so that earlier keys stay valid
        key["init_hash"] = io.array_checksum(*(np.asarray(v, float) for v in init_point))[:16]
    return key


def _record_checksum(rec: dict[str, Any]) -> str:
    """SHA-256 of a record's canonical JSON without :data:`RECORD_CHECKSUM`."""
    body = {k: v for k, v in rec.items() if k != RECORD_CHECKSUM}
    text = json.dumps(body, sort_keys=True, separators=(",", ":"), default=io.json_default)
    return hashlib.sha256(text.encode()).hexdigest()


def write_record(path: str | os.PathLike, rec: dict[str, Any]) -> None:
    """Write a record with its checksum (:data:`RECORD_CHECKSUM`): an edit that keeps the
    file valid JSON, and even its time, is found when the record is read back."""
    plain = json.loads(json.dumps(rec, default=io.json_default))  # as it is read back
    io.write_json(path, {**plain, RECORD_CHECKSUM: _record_checksum(plain)})


def read_record(path: str | os.PathLike) -> dict[str, Any]:
    """A record written by :func:`write_record`; CorruptFileError naming the file when it
    does not parse, lacks keys, or its checksum is missing or does not match."""
    rec: dict[str, Any] = io.read_json(path, required=RECORD_KEYS)
    if rec.get(RECORD_CHECKSUM) != _record_checksum(rec):
        raise io.CorruptFileError(
            f"{path}: its checksum is missing or does not match (damaged or edited)"
        )
    return rec


def record_path(records_dir: str | os.PathLike, k: int) -> Path:
    return Path(records_dir) / f"k{int(k):05d}.json"


def draws_path(draws_dir: str | os.PathLike, k: int) -> Path:
    return Path(draws_dir) / f"k{int(k):05d}.nc"


def load_record(
    path: str | Path, key: dict[str, Any] | None = None, n_theta: int | None = None
) -> dict[str, Any] | None:
    """The record at ``path`` if it exists, parses, and matches ``key`` (else None)."""
    path = Path(path)
    if not path.exists():
        return None
    try:
        rec = read_record(path)
    except io.CorruptFileError as err:
        LOG.warning("recomputing: %s", err.what)
        return None
    if rec.get("record_version") != RECORD_VERSION:
        LOG.debug(
            "recomputing %s: record version %s != %s",
            path,
            rec.get("record_version"),
            RECORD_VERSION,
        )
        return None
    if key is not None and rec.get("key") != key:
        old = rec["key"] if isinstance(rec.get("key"), dict) else {}
        changed = sorted(k for k in set(key) | set(old) if old.get(k) != key.get(k))
        LOG.debug("recomputing %s: key changed (%s)", path, ", ".join(changed))
        return None
    if (
        n_theta is not None
        and rec["map"] is not None
        and not (len(rec["map"]) == len(rec["q5"]) == len(rec["q95"]) == n_theta)
    ):
        LOG.warning("recomputing %s: Theta arrays have the wrong length", path)
        return None
    return rec


def load_records(records_dir: str | Path, ks: Iterable[int]) -> list[dict[str, Any]]:
    """Read the records of ``ks`` (CorruptFileError naming the file if one is missing/bad)."""
    out = []
    for k in ks:
        path = record_path(records_dir, k)
        if not path.exists():
            raise io.CorruptFileError(f"{path}: missing record of trajectory k={k}")
        out.append(read_record(path))
    return out


# --------------------------------------------------------------------------- batch tables
def _damaged_batch(batch_table: str | os.PathLike, what: str) -> io.CorruptFileError:
    return io.CorruptFileError(
        f"{batch_table}: {what}; this batch must be rerun (only damaged records are recomputed)"
    )


def changed_batch_records(
    batch_table: str | os.PathLike,
    records_dir: str | os.PathLike,
    draws_dir: str | os.PathLike | None = None,
    keep_draws: Iterable[int] = (),
) -> str | None:
    """Why the finished batch table ``batch_table`` no longer matches its records, or None.

    Reads only the table's ``k`` column, the records' file times and, for the
    ``keep_draws`` trajectories, their records and the kept draws' checksums (cheap enough
    for every DAG build): a record of one of those k that is missing or newer than the
    table was damaged, edited or deleted after the batch ran; a kept draws file that is
    missing, or has no checksum or another one than its record holds, was damaged (every
    record's own checksum is checked where it is read: reused by a batch, gathered).  None
    when the table does not exist (the batch is still to run) or cannot be read
    (gather_nuts reports that).
    """
    import pyarrow.parquet as pq

    table = Path(batch_table)
    keep = {int(k) for k in keep_draws}
    try:
        written = table.stat().st_mtime_ns
        ks = pq.read_table(table, columns=["k"]).column("k").to_pylist()
    except Exception:  # noqa: BLE001 - missing or unreadable: not this check's business
        return None
    for k in ks:
        path = record_path(records_dir, k)
        try:
            changed = path.stat().st_mtime_ns > written
        except FileNotFoundError:
            return str(_damaged_batch(table, f"the record of trajectory k={k} ({path}) is missing"))
        if changed:
            return str(
                _damaged_batch(
                    table,
                    f"the record of trajectory k={k} ({path}) was "
                    f"changed after this table was written",
                )
            )
        if draws_dir is None or k not in keep:
            continue  # only the records of kept draws are read (this runs on every DAG build)
        draws = draws_path(draws_dir, k)
        try:
            expected = read_record(path).get("draws_sha256")
        except io.CorruptFileError:
            return str(_damaged_batch(table, f"the record of trajectory k={k} is damaged"))
        # kept draws without their checksum count as damaged (a record without draws has none)
        if (io.file_sha256(draws) != expected) if draws.exists() else expected is not None:
            return str(_damaged_batch(table, f"the kept draws {draws} are missing or damaged"))
    return None


def check_batch_records(
    batch_table: str | os.PathLike,
    frame: pandas.DataFrame,
    model: StateSpaceModel,
    T: int,
    records_dir: str | os.PathLike,
    convergence_cfg: dict,
) -> None:
    """The per-trajectory records a batch table was built from are all there, parse and
    give exactly this table (:func:`ssmobs.nuts.record_format.records_to_frame`).

    Run by gather_nuts (the workflow also stops before it when a record is newer than its
    table, :func:`changed_batch_records`).  Raises
    :class:`~ssmobs.io.CorruptFileError` naming the batch table to delete: rerunning its
    batch recomputes the damaged records only and reuses every valid one.
    """
    from .convergence import ConvergenceSettings, apply_thresholds
    from .record_format import records_to_frame

    def damaged(what: str) -> io.CorruptFileError:
        return _damaged_batch(batch_table, what)

    recs = []
    for k in frame["k"].tolist():
        path = record_path(records_dir, k)
        if not path.exists():
            raise damaged(f"the record of trajectory k={k} ({path}) is missing")
        try:
            rec = read_record(path)
        except io.CorruptFileError as err:
            raise damaged(f"the record of trajectory k={k} is damaged ({err.args[0]})") from None
        if rec["k"] != k:
            raise damaged(f"the record {path} is of trajectory k={rec['k']}, not k={k}")
        recs.append(rec)
    try:
        rebuilt = apply_thresholds(
            records_to_frame(recs, model, T), ConvergenceSettings(**convergence_cfg)
        )
    except (KeyError, TypeError, ValueError, IndexError) as err:
        raise damaged(f"its records under {records_dir} do not form a table ({err})") from None
    if list(rebuilt.columns) != list(frame.columns) or len(rebuilt) != len(frame):
        raise damaged(f"its records under {records_dir} give other columns or rows")
    if not rebuilt.equals(frame):
        bad = [
            int(k)
            for k, (_, a), (_, b) in zip(frame["k"], rebuilt.iterrows(), frame.iterrows())
            if not a.equals(b)
        ]
        raise damaged(f"the records of trajectories k={bad} ({records_dir}) differ from it")
