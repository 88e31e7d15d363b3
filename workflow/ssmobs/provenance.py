"""Provenance of a committed reproduction: when, from which commit, on what machine, with
which Stan backend, how long, and with which config.

``python -m ssmobs.provenance --config C --outputs-dir D --started EPOCH`` writes
``D/provenance.json`` after a run (``make tables`` calls it).
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

import yaml

from . import io


def _git(*args: str) -> str:
    try:
        out = subprocess.run(["git", *args], capture_output=True, text=True, timeout=30)
    except OSError:
        return "unknown"
    return out.stdout.strip() if out.returncode == 0 else "unknown"


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


def backend_info(config: dict[str, Any]) -> dict[str, str]:
    """The concrete Stan backend the config resolves to, and its Stan version."""
    from .stan_backends import get_backend, resolve_backend

    name = resolve_backend(config.get("stan", {}).get("backend", "auto"))
    return dict(get_backend(name).identity())


def provenance(
    config_path: str | os.PathLike, started: float, finished: float, command: str, note: str = ""
) -> dict[str, Any]:
    """The provenance record of one run of ``config_path`` (see the module docstring)."""
    text = Path(config_path).read_text()
    config = yaml.safe_load(text)
    return {
        "date_utc": dt.datetime.fromtimestamp(finished, dt.timezone.utc).isoformat(
            timespec="seconds"
        ),
        "commit": _git("rev-parse", "HEAD"),
        "uncommitted_changes": bool(_git("status", "--porcelain", "--untracked-files=no")),
        "machine": machine(),
        "stan": backend_info(config),
        "wall_seconds": round(finished - started, 1),
        "command": command,
        "note": note,
        "config_file": str(config_path),
        "config_sha256": hashlib.sha256(text.encode()).hexdigest(),
        "config": config,
    }


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", required=True)
    parser.add_argument("--outputs-dir", required=True)
    parser.add_argument("--started", type=float, required=True, help="start, Unix seconds")
    parser.add_argument("--command", default="make tables")
    parser.add_argument("--note", default="", help="e.g. what an earlier, resumed run did")
    args = parser.parse_args(argv)
    record = provenance(args.config, args.started, time.time(), args.command, args.note)
    io.write_json(Path(args.outputs_dir) / "provenance.json", record)


if __name__ == "__main__":
    main()
