"""MkDocs hook: a committed run's provenance, rendered from its ``provenance.json``.

A page writes ``<!-- provenance: paper_figures/<folder> -->`` where it describes a
committed reproduction; the hook replaces it with what the file records (command, commit,
date, machine, backend, wall and CPU time, whether it started from an empty ``results/``,
the note), so that run times and dates on the site are read, never retyped.
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


def _minutes(seconds: Any) -> str:
    if seconds is None:
        return "not recorded"
    return f"{seconds:.0f} s ({seconds / 60:.1f} min)"


def render(prov: dict[str, Any]) -> str:
    """The provenance as a short Markdown list."""
    machine = prov.get("machine", {})
    stan = prov.get("stan", {})
    lines = [
        f"- **made by** `{prov['command']}` with `{prov['config_file']}` at commit "
        f"`{prov['commit'][:12]}`"
        + (" (with uncommitted changes)" if prov.get("uncommitted_changes") else "")
        + f", finished {prov['date_utc'][:16].replace('T', ' ')} UTC",
        f"- **machine**: {machine.get('cpus')} CPUs ({machine.get('cpu_model')}), "
        f"{machine.get('memory_gib')} GiB, Python {machine.get('python')}; Stan backend "
        f"{stan.get('backend')} ({stan.get('stan_version')})",
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
    if prov.get("note"):
        lines.append(f"- **note**: {prov['note']}")
    return "\n".join(lines)


def on_page_markdown(markdown: str, page: Page, config: MkDocsConfig, files: Files) -> str:
    root = Path(config.config_file_path).resolve().parent

    def replace(match: re.Match) -> str:
        path = root / match["folder"] / "provenance.json"
        return render(json.loads(path.read_text()))

    return MARKER.sub(replace, markdown)
