"""MkDocs hook: the committed figures of ``paper_figures/`` become part of the site.

The pages show the workflow's figures from where the workflow writes them instead of
copies: every ``paper_figures/**/*.png`` is added to the site at the same path, so a page
at ``docs/<page>.md`` links ``paper_figures/<folder>/<figure>.png`` as if the folder lay
inside ``docs/`` (``../paper_figures/...`` from a page one folder down).
"""

from __future__ import annotations

from pathlib import Path

from mkdocs.config.defaults import MkDocsConfig
from mkdocs.structure.files import File, Files


def on_files(files: Files, config: MkDocsConfig) -> Files:
    """Add every PNG under ``paper_figures/`` to the site's files."""
    root = Path(config.config_file_path).resolve().parent
    for png in sorted((root / "paper_figures").rglob("*.png")):
        uri = png.relative_to(root).as_posix()
        files.append(File.generated(config, uri, abs_src_path=str(png)))
    return files
