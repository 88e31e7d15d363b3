"""Import closures and syntax-tree hashes of a package's code (ssmobs.code_hashing), on small
packages written for the test: nothing here is the workflow's."""

from __future__ import annotations

from pathlib import Path

import pytest
from ssmobs.code_hashing import import_closure, syntax_digest

pytestmark = pytest.mark.unit


def _write(root: Path, files: dict[str, str]) -> Path:
    for name, text in files.items():
        (root / name).parent.mkdir(parents=True, exist_ok=True)
        (root / name).write_text(text)
    return root


def test_closure_of_named_functions_follows_only_the_code_they_run(tmp_path):
    """``"module.py:f"``: the module's top level, f and the functions f calls; imports under
    ``if TYPE_CHECKING:`` run nowhere; the packages' ``__init__.py`` run on import."""
    pkg = _write(
        tmp_path / "pkg",
        {
            "__init__.py": "",
            "a.py": "",
            "b.py": "",
            "c.py": "",
            "d.py": "",
            "typing_only.py": "",
            "sub/__init__.py": "",
            "sub/glue.py": (
                "from typing import TYPE_CHECKING\n"
                "from .. import a\n"
                "if TYPE_CHECKING:\n"
                "    from .. import typing_only\n"
                "def f():\n"
                "    from ..b import x\n"
                "    return helper()\n"
                "def helper():\n"
                "    from ..c import y\n"
                "def g():\n"
                "    from ..d import z\n"
            ),
        },
    )
    base = {"__init__.py", "a.py", "sub/__init__.py", "sub/glue.py"}
    assert set(import_closure(("sub/glue.py:f",), pkg)) == base | {"b.py", "c.py"}
    assert set(import_closure(("sub/glue.py:g",), pkg)) == base | {"d.py"}
    assert set(import_closure(("sub/glue.py",), pkg)) == base | {"b.py", "c.py", "d.py"}
    with pytest.raises(ValueError, match="no function"):
        import_closure(("sub/glue.py:nope",), pkg)
    with pytest.raises(FileNotFoundError, match="no such module"):
        import_closure(("gone.py",), pkg)


def test_closure_follows_absolute_imports_of_the_package_and_leaves_out_skipped_modules(
    tmp_path,
):
    """Absolute imports count when they name the package (its directory's name); a skipped
    module is neither listed nor followed, so what only it imports is not listed either."""
    pkg = _write(
        tmp_path / "pkg",
        {
            "__init__.py": "",
            "main.py": "import os\nimport pkg.a\nfrom pkg.b import x\nfrom . import quiet\n",
            "a.py": "",
            "b.py": "",
            "quiet.py": "from .c import y\n",
            "c.py": "",
        },
    )
    assert import_closure(("main.py",), pkg) == (
        "__init__.py",
        "a.py",
        "b.py",
        "c.py",
        "main.py",
        "quiet.py",
    )
    assert import_closure(("main.py",), pkg, frozenset({"quiet.py"})) == (
        "__init__.py",
        "a.py",
        "b.py",
        "main.py",
    )


def test_syntax_digest_keeps_docstrings_comments_and_layout_out(tmp_path):
    code = 'def f(x):\n    """Twice x."""\n    return 2 * x\n'
    same = '"""A module."""\n\n\ndef f(x):  # doubles\n    """Two times x."""\n    return 2*x\n'
    other = 'def f(x):\n    """Twice x."""\n    return 3 * x\n'
    digests = []
    for i, text in enumerate((code, same, other)):
        (tmp_path / f"m{i}.py").write_text(text)
        digests.append(syntax_digest(tmp_path / f"m{i}.py"))
    assert digests[0] == digests[1] != digests[2]
    assert len(digests[0]) == 16


def test_a_module_edited_in_the_same_process_is_read_again(tmp_path):
    """Each module's imports are parsed once per process and content (a Snakemake parse
    reaches most modules from several stages): an edit between two closures is seen, and a
    module added after the first closure is found."""
    pkg = _write(tmp_path / "pkg", {"__init__.py": "", "a.py": "", "b.py": "", "glue.py": ""})
    (pkg / "glue.py").write_text("from . import a\n")
    assert import_closure(("glue.py",), pkg) == ("__init__.py", "a.py", "glue.py")
    (pkg / "glue.py").write_text("from . import a, b\nfrom . import late\n")
    assert import_closure(("glue.py",), pkg) == ("__init__.py", "a.py", "b.py", "glue.py")
    (pkg / "late.py").write_text("")
    assert import_closure(("glue.py",), pkg) == (
        "__init__.py",
        "a.py",
        "b.py",
        "glue.py",
        "late.py",
    )


def test_a_syntax_digest_edited_in_the_same_process_is_computed_again(tmp_path):
    """The digests are kept per process by content: an edit between two calls is seen, and
    going back to the first text gives the first digest."""
    path = tmp_path / "m.py"
    digests = []
    for body in ("x = 1\n", "x = 2\n", "x = 1\n"):
        path.write_text(body)
        digests.append(syntax_digest(path))
    assert digests[0] == digests[2] != digests[1]
