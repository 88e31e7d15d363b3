"""Provenance of a committed reproduction: when, from which commit, on what machine, with
which Stan backend and gradient path (``stan.gradients``), how long, and with which config.

``python -m ssmobs.provenance --config C --outputs-dir D -- COMMAND ...`` runs the command
(the make targets pass their Snakemake call) and, when it succeeds, writes
``D/provenance.json`` with its wall and CPU time and whether it started from an empty
``results/`` (a committed output must be exactly what its recorded commit produces).
``--started EPOCH`` instead of a command records a run made before (with ``--finished``,
``--cpu-seconds`` and ``--from-empty-results`` when they were measured, e.g. by
``benchmarks/newcomer.sh``).
"""

from __future__ import annotations

import argparse
import datetime as dt
import hashlib
import os
import platform
import subprocess
import time
from pathlib import Path
from typing import Any

from . import io
from .config.validation import read_config_file


def _git(*args: str) -> str:
    try:
        out = subprocess.run(["git", *args], capture_output=True, text=True, timeout=30)
    except OSError:
        return "unknown"
    return out.stdout.strip() if out.returncode == 0 else "unknown"


def uncommitted_files(outputs_dir: str | os.PathLike = "") -> list[str]:
    """Tracked files that differ from the commit, other than those under ``outputs_dir``
    (the outputs this run writes); ``["unknown"]`` when git cannot tell."""
    exclude = [f":!{outputs_dir}"] if str(outputs_dir) else []
    out = _git("diff", "--name-only", "HEAD", "--", ".", *exclude)
    if out == "unknown":
        return ["unknown"]
    return out.splitlines()


def machine() -> dict[str, Any]:
    """CPU count and model, memory, OS and Python of this machine."""
    cpu, mem = "unknown CPU", None
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemTotal"):
                mem = round(int(line.split()[1]) / 1024**2, 1)
                break
    except OSError:
        pass
    return {
        "cpus": os.cpu_count(),
        "cpu_model": cpu,
        "memory_gib": mem,
        "os": platform.platform(),
        "python": platform.python_version(),
    }


def numerics() -> dict[str, Any]:
    """What the numbers depended on (:func:`ssmobs.kernels.record`: CPU model and flags, the
    BLAS libraries and the kernel they use, NumPy's dispatch, versions), read in a child
    process that starts as every job does, with :func:`ssmobs.kernels.environment`."""
    import json
    import sys

    from . import kernels

    code = "import json; from ssmobs import kernels; print(json.dumps(kernels.record()))"
    out = subprocess.run(
        [sys.executable, "-c", code],
        env={**os.environ, **kernels.environment()},
        capture_output=True,
        text=True,
        timeout=120,
    )
    if out.returncode != 0:
        return {"error": out.stderr.strip().splitlines()[-1:] or ["unknown"]}
    return dict(json.loads(out.stdout))


def gradient_paths(config: dict[str, Any]) -> dict[str, Any]:
    """How NUTS got its gradients: the config key ``stan.gradients`` (the schema's default
    where the file does not set it) and, per model of a scenario that samples, the path its
    program took (``analytic`` for a model without ``stan/<model>.stan`` whatever the key:
    :func:`ssmobs.nuts.stan_program.stan_program`)."""
    from .config.blocks import gradient_path, stan_gradients
    from .stan_backends import has_stan_file

    block = config.get("stan") or {}
    gradients = stan_gradients(block)
    by_model = {
        str(entry["model"]): gradient_path(block, has_stan_file(str(entry["model"])))
        for entry in config.get("scenarios") or []
        if isinstance(entry, dict) and "model" in entry and entry.get("stan", True) is not False
    }
    return {"gradients": gradients, "gradients_by_model": dict(sorted(by_model.items()))}


def backend_info(config: dict[str, Any]) -> dict[str, Any]:
    """The concrete Stan backend the config resolves to, its Stan version and the path of
    NUTS's gradients (``autodiff`` or ``analytic``, :func:`gradient_paths`)."""
    from .stan_backends import get_backend, resolve_backend

    name = resolve_backend((config.get("stan") or {}).get("backend", "auto"))
    return {**get_backend(name).identity(), **gradient_paths(config)}


def results_empty(results: str | os.PathLike = "results") -> bool:
    """True when ``results/`` does not exist or holds nothing."""
    path = Path(results)
    return not path.exists() or not any(path.iterdir())


def provenance(
    config_path: str | os.PathLike,
    started: float,
    finished: float,
    command: str,
    note: str = "",
    cpu_seconds: float | None = None,
    from_empty_results: bool | None = None,
    outputs_dir: str | os.PathLike = "",
) -> dict[str, Any]:
    """The provenance record of one run of ``config_path`` (see the module docstring)."""
    text = Path(config_path).read_text()
    config = read_config_file(config_path)  # duplicate keys refused
    changed = uncommitted_files(outputs_dir)
    return {
        "date_utc": dt.datetime.fromtimestamp(finished, dt.timezone.utc).isoformat(
            timespec="seconds"
        ),
        "commit": _git("rev-parse", "HEAD"),
        # changes to tracked files other than the outputs this run writes, and which
        "uncommitted_changes": bool(changed),
        "uncommitted_files": changed,
        "machine": machine(),
        "numerics": numerics(),
        "stan": backend_info(config),
        "wall_seconds": round(finished - started, 1),
        "cpu_seconds": None if cpu_seconds is None else round(cpu_seconds, 1),
        "started_from_empty_results": from_empty_results,
        "command": command,
        "note": note,
        "config_file": str(config_path),
        "config_sha256": hashlib.sha256(text.encode()).hexdigest(),
        "config": config,
    }


def main(argv: list[str] | None = None) -> int:
    import resource

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", required=True)
    parser.add_argument("--outputs-dir", help="default: the config's outputs_dir")
    parser.add_argument("--started", type=float, help="start of a run made before, Unix seconds")
    parser.add_argument("--finished", type=float, help="its end, Unix seconds (default: now)")
    parser.add_argument("--cpu-seconds", type=float, help="its CPU time, when measured")
    parser.add_argument(
        "--from-empty-results", choices=("yes", "no"), help="whether it began with no results/"
    )
    parser.add_argument("--command", default="make tables")
    parser.add_argument("--note", default="", help="e.g. what an earlier, resumed run did")
    parser.add_argument("run", nargs=argparse.REMAINDER, help="-- the command to run")
    args = parser.parse_args(argv)
    run = args.run[1:] if args.run[:1] == ["--"] else args.run
    if run and (args.finished, args.cpu_seconds, args.from_empty_results) != (None,) * 3:
        parser.error(
            "--finished, --cpu-seconds and --from-empty-results describe a run made before"
        )
    outputs_dir = args.outputs_dir or read_config_file(args.config)["outputs_dir"]
    cpu = args.cpu_seconds
    empty = None if args.from_empty_results is None else args.from_empty_results == "yes"
    finished = args.finished  # None with a command: it ends now
    if run:
        empty = results_empty()
        started = time.time()
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        code = subprocess.call(run)
        if code != 0:
            return code
        after = resource.getrusage(resource.RUSAGE_CHILDREN)  # the run's whole process tree
        cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    elif args.started is not None:
        started = args.started
    else:
        parser.error("give --started or a command after --")
    record = provenance(
        args.config,
        started,
        time.time() if finished is None else finished,
        args.command,
        args.note,
        cpu,
        empty,
        outputs_dir,
    )
    io.write_json(Path(outputs_dir) / "provenance.json", record)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
