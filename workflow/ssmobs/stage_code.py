"""The code each stage of the workflow runs, as hashed into its cache keys
(:mod:`ssmobs.cache_keys`): the stage's code entries in the table of stages
(:data:`ssmobs.stage_table.STAGES`), closed over their imports inside the package
(:func:`module_closure`, without the modules that never change a number:
:data:`NEUTRAL_MODULES`), its files outside the import graph and its rule scripts; a model's
own modules (:func:`model_closure`) and what they import outside the package
(:func:`outside_code`); and the digests of payloads and files.
"""

from __future__ import annotations

import functools
import hashlib
import json
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from . import io
from .code_hashing import environment_dirs, import_closure, outside_modules, syntax_digest
from .stage_table import PACKAGE_DIR, STAGES

#: the repository (or workflow copy) this package belongs to
REPO_DIR = PACKAGE_DIR.parents[1]
#: hex digits of a key
KEY_LENGTH = 12

#: modules that only log, plan or describe and never change a number or a file's content
NEUTRAL_MODULES: frozenset[str] = frozenset(
    {
        "log.py",
        "config/budget.py",
        "config/preflight.py",
        "config/validation.py",
        "config/maps.py",
        "config/schema.py",
        "config/files.py",
        "provenance.py",
    }
)


# --------------------------------------------------------------------------- hashing
def digest(payload: Any) -> str:
    """:data:`KEY_LENGTH` hex digits of SHA-256 over canonical JSON of ``payload``."""
    text = json.dumps(payload, sort_keys=True, separators=(",", ":"), default=io.json_default)
    return hashlib.sha256(text.encode()).hexdigest()[:KEY_LENGTH]


def file_digest(path: str | Path) -> str:
    """SHA-256 (16 hex digits) of a file's bytes."""
    return io.file_sha256(path)[:16]


@functools.cache
def module_closure(entries: tuple[str, ...], package_dir: Path = PACKAGE_DIR) -> tuple[str, ...]:
    """The modules that ``entries`` (``"module.py"`` or ``"stages/x.py:f,g"``, see
    :attr:`ssmobs.stage_table.Stage.code`) run: the entries, every package module they
    import, directly or not, and the ``__init__.py`` of their packages (sorted relative
    paths), without
    :data:`NEUTRAL_MODULES` (:func:`ssmobs.code_hashing.import_closure`)."""
    return import_closure(entries, package_dir, NEUTRAL_MODULES)


#: the model registry (:mod:`ssmobs.models`), which every stage that takes a model runs
MODEL_REGISTRY = "models/__init__.py"


def model_closure(model: str, package_dir: Path = PACKAGE_DIR) -> tuple[str, ...]:
    """The modules model ``model`` runs: ``models/<model>.py`` and its :func:`module_closure`
    without the registry's own (:data:`MODEL_REGISTRY` and what it imports, e.g.
    ``models/base.py``), which is keyed with the code of every stage that takes a model."""
    registry = set(module_closure((MODEL_REGISTRY,), package_dir))
    own = module_closure((f"models/{model}.py",), package_dir)
    return tuple(f for f in own if f not in registry)


def _module_name(relative: str, package_dir: Path) -> tuple[str, bool]:
    """The dotted name of the package module ``relative`` (a path below ``package_dir``),
    with whether it is a package's ``__init__.py``."""
    parts = [package_dir.name, *Path(relative).with_suffix("").parts]
    is_package = parts[-1] == "__init__"
    return ".".join(parts[:-1] if is_package else parts), is_package


def outside_code(files: Iterable[str], package_dir: Path = PACKAGE_DIR) -> dict[str, str]:
    """``"import:<name>"`` -> hash of every module outside the package and outside the
    pinned environment (its standard library and site-packages) that the package modules
    ``files`` import, directly or not (:func:`ssmobs.code_hashing.outside_modules`): a
    user's helper on ``PYTHONPATH``, a module of the project tree such as
    ``workflow/myhelper.py``; with the package modules those import (by their paths).  A
    Python module by its :func:`syntax_digest`, a compiled one by its bytes.  Found as the
    running interpreter imports them (the workflow's jobs inherit its ``PYTHONPATH``)."""
    modules = [(*_module_name(f, package_dir), package_dir / f) for f in files]
    outside, own = outside_modules(
        [(name, path, is_pkg) for name, is_pkg, path in modules],
        package_dir.name,
        environment_dirs(),
    )
    out: dict[str, str] = {}
    for name, path in sorted(outside.items()):
        out[f"import:{name}"] = syntax_digest(path) if path.suffix == ".py" else file_digest(path)
    entries = []
    for name in own:
        parts = name.split(".")[1:]
        candidates = [Path(*parts).with_suffix(".py")] if parts else []
        for candidate in [*candidates, Path(*parts, "__init__.py")]:
            if (package_dir / candidate).is_file():
                entries.append(str(candidate))
    if entries:
        for f in module_closure(tuple(sorted(entries)), package_dir):
            out.setdefault(f, syntax_digest(package_dir / f))
    return out


def model_code(model: str, package_dir: Path = PACKAGE_DIR) -> dict[str, str]:
    """The code of ``model`` as every key that runs it holds it: its module and the package
    modules it runs (:func:`model_closure`) by their :func:`syntax_digest` (a comment-only
    edit reruns nothing), and what they import from outside the package
    (:func:`outside_code`)."""
    files = model_closure(model, package_dir)
    out = {f: syntax_digest(package_dir / f) for f in files}
    return {**out, **outside_code(files, package_dir)}


def code_digest(stage: str, package_dir: Path = PACKAGE_DIR) -> dict[str, str]:
    """File -> hash of the code a stage runs: its module closure (its stage module in
    :mod:`ssmobs.stages`, the glue that writes its outputs, and what that imports), its
    extra files and its rule scripts.  The rule files (``workflow/rules/*.smk``) are not
    hashed: what they decide (paths, params) is keyed."""
    entry = STAGES[stage]
    files = set(module_closure(entry.code, package_dir)) | set(entry.extra_files)
    out = {f: file_digest(package_dir / f) for f in sorted(files)}
    for script in entry.scripts:
        path = package_dir.parent / "scripts" / f"{script}.py"
        out[f"scripts/{script}.py"] = file_digest(path)
    return out
