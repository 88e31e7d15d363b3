"""MkDocs hook: a committed run's provenance, rendered from its ``provenance.json``.

A page writes ``<!-- provenance: paper_figures/<folder> -->`` where it describes a
committed reproduction; the hook replaces it with what the file records (command, commit,
date, machine, backend, wall and CPU time, whether it started from an empty ``results/``,
the note), so that run times and dates on the site are read, never retyped.
``<!-- kernels-status -->`` becomes a table of every committed folder under
``paper_figures/`` with the numerical kernels it was made with (``numerics`` in its
provenance; docs/reproducibility.md).
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

from mkdocs.config.defaults import MkDocsConfig
from mkdocs.structure.files import Files
from mkdocs.structure.pages import Page

MARKER = re.compile(r"<!-- provenance: (?P<folder>[\w./-]+) -->")
STATUS_MARKER = "<!-- kernels-status -->"


def _minutes(seconds: Any) -> str:
    if seconds is None:
        return "not recorded"
    return f"{seconds:.0f} s ({seconds / 60:.1f} min)"


def _uncommitted(prov: dict[str, Any], shown: int = 3) -> str:
    """`` (with uncommitted changes ...)`` naming the changed files where they were recorded."""
    if not prov.get("uncommitted_changes"):
        return ""
    files = prov.get("uncommitted_files")
    if not files:
        return " (with uncommitted changes)"
    names = ", ".join(f"`{f}`" for f in files[:shown])
    more = f" and {len(files) - shown} more" if len(files) > shown else ""
    return f" (with uncommitted changes to {names}{more})"


def gradients(prov: dict[str, Any]) -> str:
    """NUTS's gradient path (config key ``stan.gradients``): as recorded, else as the recorded
    config sets it, else ``autodiff`` (the schema's default, and the only path before the key)."""
    recorded = prov.get("stan", {}).get("gradients")
    if recorded is None:
        recorded = ((prov.get("config") or {}).get("stan") or {}).get("gradients", "autodiff")
    return f"`{recorded}`"


def render(prov: dict[str, Any]) -> str:
    """The provenance as a short Markdown list."""
    machine = prov.get("machine", {})
    stan = prov.get("stan", {})
    lines = [
        f"- **made by** `{prov['command']}` with `{prov['config_file']}` at commit "
        f"`{prov['commit'][:12]}`"
        + _uncommitted(prov)
        + f", finished {prov['date_utc'][:16].replace('T', ' ')} UTC",
        f"- **machine**: {machine.get('cpus')} CPUs ({machine.get('cpu_model')}), "
        f"{machine.get('memory_gib')} GiB, Python {machine.get('python')}; Stan backend "
        f"{stan.get('backend')} ({stan.get('stan_version')}), gradients {gradients(prov)}",
        f"- **wall time** {_minutes(prov.get('wall_seconds'))}, **CPU time** "
        f"{_minutes(prov.get('cpu_seconds'))}"
        + (
            "; started from an empty `results/`"
            if prov.get("started_from_empty_results")
            else "; started with earlier results in `results/`"
            if prov.get("started_from_empty_results") is False
            else ""
        ),
    ]
    lines.append(f"- **kernels**: {kernels(prov)}")
    if prov.get("note"):
        lines.append(f"- **note**: {prov['note']}")
    return "\n".join(lines)


def kernels(prov: dict[str, Any]) -> str:
    """The numerical kernels a run computed with, from its ``numerics`` record."""
    numerics = prov.get("numerics")
    if not numerics:
        return (
            "made before the fixed kernels: its commit gives these numbers only on a CPU and "
            "environment like this machine's (OpenBLAS Haswell by its environment, NumPy up "
            "to AVX-512, the default thread count)"
        )
    blas = ", ".join(f"{b['api']} {b['kernel']} x{b['threads']}" for b in numerics["blas"])
    dispatch = (numerics.get("numpy_dispatch") or ["baseline"])[-1]
    numpy = f"NumPy {numerics['numpy']} up to {dispatch}"
    return f"fixed: BLAS {blas}, {numpy}; {numerics['guarantee']}"


def status_table(root: Path) -> str:
    """Every committed folder with the date, commit, CPU and kernels of its run."""
    rows = ["| folder | made | commit | CPU | kernels |", "|---|---|---|---|---|"]
    for path in sorted((root / "paper_figures").rglob("provenance.json")):
        prov = json.loads(path.read_text())
        folder = path.parent.relative_to(root)
        fixed = "fixed" if prov.get("numerics") else "before the fixed kernels"
        cpu = prov.get("machine", {}).get("cpu_model", "not recorded")
        rows.append(
            f"| `{folder}` | {prov['date_utc'][:10]} | `{prov['commit'][:8]}` | {cpu} | {fixed} |"
        )
    return "\n".join(rows)


def on_page_markdown(markdown: str, page: Page, config: MkDocsConfig, files: Files) -> str:
    root = Path(config.config_file_path).resolve().parent

    def replace(match: re.Match) -> str:
        path = root / match["folder"] / "provenance.json"
        return render(json.loads(path.read_text()))

    if STATUS_MARKER in markdown:
        markdown = markdown.replace(STATUS_MARKER, status_table(root))
    return MARKER.sub(replace, markdown)
