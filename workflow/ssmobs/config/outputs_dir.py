"""Where a run writes its tables and figures: the checks of ``outputs_dir``.

A relative path inside the working directory, outside the folders that hold the workflow,
its cache or git's data (:data:`RESERVED_DIRS`), also once its symbolic links are followed.
Imports only :mod:`ssmobs.config.schema`.
"""

from __future__ import annotations

import os
from pathlib import Path

from .schema import short_repr

#: top-level folders of the working directory that hold the workflow, its cache or git's
#: data: no outputs_dir lies in one of them
RESERVED_DIRS = frozenset(
    {".git", ".snakemake", ".venv", "benchmarks", "config", "docs", "envs", "profiles"}
    | {"results", "site", "stan", "tests", "workflow"}
)


def outputs_dir_problems(config: dict) -> list[str]:
    """outputs_dir: a relative path that stays inside the working directory, outside the
    folders of :data:`RESERVED_DIRS`, also once its symbolic links are followed (a link
    ``paper_figures/x -> ../results`` would put the tables beside the stages' folders)."""
    value = config["outputs_dir"]
    if value.startswith("/") or ".." in value.split("/"):
        return [
            f"outputs_dir = {short_repr(value)}: must be a relative path inside the working "
            f"directory; allowed: no leading '/' and no '..' part (e.g. paper_figures/mine)"
        ]
    parts = [p for p in value.split("/") if p not in ("", ".")]
    if not parts or parts[0] in RESERVED_DIRS:
        return [
            f"outputs_dir = {short_repr(value)}: would write into "
            f"{'the working directory itself' if not parts else repr(parts[0] + '/')}, which "
            f"holds the workflow, its cache or git's data; allowed: a folder outside "
            f"{', '.join(sorted(RESERVED_DIRS))} (e.g. paper_figures/mine)"
        ]
    cwd = Path.cwd().resolve()
    real = (cwd / value).resolve()  # symbolic links followed, also of missing folders' parents
    inside = real.relative_to(cwd).parts if real.is_relative_to(cwd) else None
    if inside is not None and (not inside or inside[0] in RESERVED_DIRS):
        target = f"inside {inside[0]}/" if inside else "the working directory itself"
        return [
            f"outputs_dir = {short_repr(value)}: resolves (symbolic links followed) to "
            f"{os.path.relpath(real, cwd)}, {target}, which holds the workflow, its "
            f"cache or git's data; allowed: a folder that resolves outside "
            f"{', '.join(sorted(RESERVED_DIRS))} (e.g. paper_figures/mine)"
        ]
    return []
