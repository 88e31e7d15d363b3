"""The session-wide smoke run shared by the workflow tests."""

from __future__ import annotations

import hashlib
import os
import shutil
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))

from helpers import COPY, REPO, SMOKE, make_workdir, snakemake  # noqa: E402

#: a folder where the smoke run is kept for the next pytest session of the same tree
#: (.ci/run sets it: `make test-slow` then uses the run `make test` made, not a second one)
STORE_ENV = "SSMOBS_TEST_SMOKE_STORE"


def tree_key() -> str:
    """A content key of what a run depends on: every file make_workdir copies (the
    workflow, configs, Stan programs, environment files, profiles) and the interpreter."""
    h = hashlib.sha256(f"{sys.executable}\n{sys.version}\n".encode())
    for name in COPY:
        src = REPO / name
        files = sorted(src.rglob("*")) if src.is_dir() else [src]
        for f in files:
            if not f.is_file() or "__pycache__" in f.parts or ".egg-info" in str(f):
                continue
            h.update(f"{f.relative_to(REPO)}\n".encode() + f.read_bytes())
    return h.hexdigest()[:20]


def copy_run(src: Path, dest: Path) -> Path:
    """A finished run under another folder (without Snakemake's locks), times kept."""
    shutil.copytree(src, dest, symlinks=True, ignore=shutil.ignore_patterns("locks"))
    return dest


@pytest.fixture(scope="session")
def smoke_run(tmp_path_factory) -> Path:
    """The smoke workflow run once, uninterrupted, with --cores 2.  With $SSMOBS_TEST_SMOKE_STORE
    set, a copy of it is kept there under the tree's content key, taken before any test uses
    it, and a later session of the same tree starts from a copy of that copy."""
    store = os.environ.get(STORE_ENV)
    kept = Path(store) / tree_key() if store else None
    dest = tmp_path_factory.mktemp("smoke") / "run"
    if kept is not None and (kept / "finished").is_file():
        return copy_run(kept / "run", dest)
    workdir = make_workdir(dest)
    snakemake(workdir, "--cores", "2", *SMOKE)
    if kept is not None:
        shutil.rmtree(kept, ignore_errors=True)
        copy_run(workdir, kept / "run")
        (kept / "finished").write_text("the smoke run finished; run/ is its copy\n")
    return workdir
