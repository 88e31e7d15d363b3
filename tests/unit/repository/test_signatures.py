"""No function of the package takes more than 8 positional parameters or 12 in all (issue
50): a longer list is an object waiting to exist (e.g. :class:`ssmobs.nuts.batch.NutsBatch`),
or its trailing settings are keyword-only."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest
from repo_paths import PACKAGE_DIR

pytestmark = pytest.mark.unit
MAX_POSITIONAL = 8
MAX_PARAMETERS = 12


def long_signatures(package_dir: Path) -> list[str]:
    """``module:line name (positional, all)`` of every function or method over the limits;
    ``self`` and ``cls`` do not count, ``*args`` and ``**kwargs`` count as one each."""
    found = []
    for path in sorted(package_dir.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
            if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                continue
            args = node.args
            positional = [a.arg for a in [*args.posonlyargs, *args.args]]
            if positional and positional[0] in ("self", "cls"):
                positional = positional[1:]
            n_pos = len(positional) + (args.vararg is not None)
            n_all = n_pos + len(args.kwonlyargs) + (args.kwarg is not None)
            if n_pos > MAX_POSITIONAL or n_all > MAX_PARAMETERS:
                where = path.relative_to(package_dir.parent)
                found.append(f"{where}:{node.lineno} {node.name} ({n_pos}, {n_all})")
    return found


def test_no_function_of_the_package_has_a_long_parameter_list():
    assert long_signatures(PACKAGE_DIR) == []


def test_a_long_parameter_list_is_found(tmp_path: Path):
    package = tmp_path / "pkg"
    package.mkdir()
    (package / "a.py").write_text(
        "def nine(a, b, c, d, e, f, g, h, i):\n    pass\n"
        "def eight_and_keywords(a, b, c, d, e, f, g, h, *, i=1, j=2, k=3, l=4):\n    pass\n"
        "def thirteen(a, *, b, c, d, e, f, g, h, i, j, k, l, m):\n    pass\n"
        "class C:\n    def method(self, a, b, c, d, e, f, g, h):\n        pass\n"
        "    def more(self, a, b, c, d, e, f, g, h, *args):\n        pass\n"
    )
    assert long_signatures(package) == [
        "pkg/a.py:1 nine (9, 9)",
        "pkg/a.py:5 thirteen (1, 13)",
        "pkg/a.py:10 more (9, 9)",
    ]
