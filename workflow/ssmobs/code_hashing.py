"""Which modules of a Python package a piece of its code runs, and a hash of a module that
ignores its docstrings: what keys a result by the code that made it.

- :func:`import_closure`: the package modules that entries (``"module.py"``, or
  ``"module.py:f,g"`` for the functions ``f``, ``g`` of a module) run, found by reading
  their imports in the syntax tree, directly or not, with the ``__init__.py`` of their
  packages;
- :func:`syntax_digest`: a module's syntax tree without its docstrings, so that an edit of
  a comment, a docstring or the layout keeps the hash;
- :func:`outside_modules`: the modules outside the package and outside the pinned
  environment (:func:`environment_dirs`) that package modules import, directly or not (a
  user's helper module on ``PYTHONPATH``, a module of the project tree).

Imports are read wherever they run: import statements at the top level and inside
functions, and ``importlib.import_module`` / ``__import__`` of a string literal
(:func:`dynamic_import`); a model's code that imports by a name that is no literal cannot
be keyed and is refused (:func:`refuse_unfollowable_imports`).

Nothing here knows the workflow: the package's directory and the modules to leave out are
arguments (:mod:`ssmobs.cache_keys` names the workflow's).
"""

from __future__ import annotations

import ast
import hashlib
import importlib.machinery
import importlib.util
import site
import sys
import sysconfig
from collections.abc import Iterable
from pathlib import Path

_DOCUMENTED = (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)


#: source bytes' SHA-256 -> :func:`syntax_digest`: each module parsed once per process,
#: however many stages' keys hash it (keyed by content, so an edited file is read again)
_SYNTAX_DIGESTS: dict[bytes, str] = {}


def syntax_digest(path: str | Path) -> str:
    """SHA-256 (16 hex digits) of a Python module's syntax tree (``ast.dump``, decoded as
    Python decodes the file) without its docstrings: what the module computes, so an edit
    of a comment, a docstring or the layout keeps it; another Python version may change
    it (which recomputes)."""
    source = Path(path).read_bytes()
    key = hashlib.sha256(source).digest()
    if key not in _SYNTAX_DIGESTS:
        tree = ast.parse(source, filename=str(path))
        for node in ast.walk(tree):
            if isinstance(node, _DOCUMENTED) and ast.get_docstring(node, clean=False) is not None:
                node.body = node.body[1:] or [ast.Pass()]
        _SYNTAX_DIGESTS[key] = hashlib.sha256(ast.dump(tree).encode()).hexdigest()[:16]
    return _SYNTAX_DIGESTS[key]


def _module_file(name: str, package_dir: Path) -> Path | None:
    """The file of module ``name`` (dotted, relative to the package), or None."""
    base = package_dir.joinpath(*name.split(".")) if name else package_dir
    if base.with_suffix(".py").is_file():
        return base.with_suffix(".py")
    if (base / "__init__.py").is_file():
        return base / "__init__.py"
    return None


def _is_type_checking(node: ast.If) -> bool:
    """``if TYPE_CHECKING:`` or ``if typing.TYPE_CHECKING:`` (its body is never run)."""
    test = node.test
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"
    )


def _walk(nodes: Iterable[ast.AST]) -> list[ast.AST]:
    """``nodes`` and every node under them, without the bodies of ``if TYPE_CHECKING:``."""
    out: list[ast.AST] = []
    todo = list(nodes)
    while todo:
        node = todo.pop()
        if isinstance(node, ast.If) and _is_type_checking(node):
            todo.extend(node.orelse)
            continue
        out.append(node)
        todo.extend(ast.iter_child_nodes(node))
    return out


_FUNCTION_DEFS = (ast.FunctionDef, ast.AsyncFunctionDef)


def _runtime_nodes(tree: ast.Module, functions: frozenset[str] | None) -> list[ast.AST]:
    """The nodes of a module that run: all of them (``functions`` None), or the module's
    top level (with its functions' decorators and defaults) and the bodies of ``functions``
    and of every function of the module they name, directly or not."""
    if functions is None:
        return _walk(tree.body)
    defs = {n.name: n for n in tree.body if isinstance(n, _FUNCTION_DEFS)}
    unknown = sorted(functions - set(defs))
    if unknown:
        raise ValueError(f"no function(s) {unknown} at the top level of the module")
    top: list[ast.AST] = [n for n in tree.body if not isinstance(n, _FUNCTION_DEFS)]
    for d in defs.values():  # run when the module is imported
        top += [*d.decorator_list, *d.args.defaults]
        top += [v for v in d.args.kw_defaults if v is not None]
    nodes = _walk(top)
    todo = [*functions, *(n.id for n in nodes if isinstance(n, ast.Name) and n.id in defs)]
    done: set[str] = set()
    while todo:
        name = todo.pop()
        if name in done:
            continue
        done.add(name)
        body = _walk(defs[name].body)
        nodes += body
        todo += [n.id for n in body if isinstance(n, ast.Name) and n.id in defs]
    return nodes


class DynamicImportError(ValueError):
    """A module imports code by a form that cannot be followed (a non-literal name), so the
    code it runs cannot be keyed; the message names the file and line."""


#: calls that import the module their first argument names (``importlib.import_module``,
#: ``__import__``): followed where that name is a string literal
_IMPORT_CALLS = frozenset({"import_module", "__import__"})
#: calls that load code no literal module name shows (a file path, a loader)
_LOADER_CALLS = frozenset({"spec_from_file_location", "SourceFileLoader", "run_path"})


def _argument(call: ast.Call, position: int, keyword: str) -> ast.expr | None:
    """The argument of ``call`` at ``position`` or named ``keyword``, or None."""
    if len(call.args) > position:
        return call.args[position]
    return next((k.value for k in call.keywords if k.arg == keyword), None)


def _literal(node: ast.expr | None) -> object:
    return node.value if isinstance(node, ast.Constant) else None


def _called_name(call: ast.Call) -> str | None:
    func = call.func
    if isinstance(func, ast.Name):
        return func.id
    return func.attr if isinstance(func, ast.Attribute) else None


def dynamic_import(call: ast.Call) -> list[tuple[int, str]] | None:
    """What the call ``call`` imports: [] for a call that imports nothing, a list of
    (level, name) for ``importlib.import_module`` or ``__import__`` of a string literal
    (level > 0: relative to the calling module's package, as ``__package__`` or a literal
    package names it; a literal package resolves the name, level 0), None for an import or
    a load that cannot be followed (a name that is no literal, a file loader)."""
    called = _called_name(call)
    if called in _LOADER_CALLS:
        return None
    if called not in _IMPORT_CALLS:
        return []
    name = _literal(_argument(call, 0, "name"))
    if not isinstance(name, str) or not name.strip("."):
        return None
    level = len(name) - len(name.lstrip("."))
    name = name.lstrip(".")
    if called == "__import__":
        level_arg = _argument(call, 4, "level")
        given = 0 if level_arg is None else _literal(level_arg)
        if not isinstance(given, int) or isinstance(given, bool):
            return None
        level = given
        fromlist = _argument(call, 3, "fromlist")
        names = [] if fromlist is None else getattr(fromlist, "elts", None)
        if names is None or not all(isinstance(_literal(n), str) for n in names):
            return None
        return [(level, name), *((level, f"{name}.{_literal(n)}") for n in names)]
    if level:
        package = _argument(call, 1, "package")
        if isinstance(package, ast.Name) and package.id in ("__package__", "__name__"):
            return [(level, name)]
        anchor = _literal(package)
        if not isinstance(anchor, str):
            return None
        parts = anchor.split(".")
        return [(0, ".".join([*parts[: len(parts) - (level - 1)], name]))]
    return [(0, name)]


def unfollowable_imports(path: str | Path) -> list[int]:
    """The lines of ``path`` that import or load code by a form :func:`dynamic_import`
    cannot follow (anywhere in its code but under ``if TYPE_CHECKING:``)."""
    tree = ast.parse(Path(path).read_bytes(), filename=str(path))
    return sorted(
        node.lineno
        for node in _walk(tree.body)
        if isinstance(node, ast.Call) and dynamic_import(node) is None
    )


def refuse_unfollowable_imports(path: str | Path, module: str) -> None:
    """Raise :class:`DynamicImportError` (one line naming ``module``, its file and line)
    when ``path`` imports code by a form that cannot be followed, so cannot be keyed."""
    lines = unfollowable_imports(path)
    if lines:
        raise DynamicImportError(
            f"module {module} ({path}, line {lines[0]}) imports or loads code by a name that "
            f"is no string literal, so the code it runs cannot be keyed and its results could "
            f"be reused after that code changed: import it with an import statement or "
            f"importlib.import_module('<name>')"
        )


#: one import statement where a module's code runs: ("from", level, module, names) or
#: ("import", 0, None, names)
_ImportSpec = tuple[str, int, str | None, tuple[str, ...]]
#: (source text's SHA-256, functions) -> the module's import statements: a parse and walk
#: of each module once per process, however many closures reach it (keyed by content, so an
#: edited file is read again)
_IMPORT_SPECS: dict[tuple[bytes, frozenset[str] | None], tuple[_ImportSpec, ...]] = {}


def _import_specs(
    source: str, path: Path, functions: frozenset[str] | None
) -> tuple[_ImportSpec, ...]:
    """The import statements of the module ``source`` where its code runs
    (:func:`_runtime_nodes`), in the order of the walk."""
    key = (hashlib.sha256(source.encode()).digest(), functions)
    if key not in _IMPORT_SPECS:
        tree = ast.parse(source, filename=str(path))
        specs: list[_ImportSpec] = []
        for node in _runtime_nodes(tree, functions):
            if isinstance(node, ast.ImportFrom):
                names = tuple(alias.name for alias in node.names)
                specs.append(("from", node.level, node.module, names))
            elif isinstance(node, ast.Import):
                specs.append(("import", 0, None, tuple(alias.name for alias in node.names)))
            elif isinstance(node, ast.Call):  # importlib.import_module("..."), __import__
                for level, name in dynamic_import(node) or []:
                    if level:
                        specs.append(("from", level, name, ()))
                    else:
                        specs.append(("import", 0, None, (name,)))
        _IMPORT_SPECS[key] = tuple(specs)
    return _IMPORT_SPECS[key]


def _imports(path: Path, package_dir: Path, functions: frozenset[str] | None = None) -> set[Path]:
    """Package modules that ``path`` imports where its code runs (:func:`_runtime_nodes`:
    relative and absolute imports of the package (named as ``package_dir``) at the top level
    and inside functions, not those under ``if TYPE_CHECKING:``)."""
    package = package_dir.name
    rel = path.relative_to(package_dir)
    pkg = list(rel.with_suffix("").parts)[:-1]
    found: set[Path] = set()
    for kind, level, module_name, names in _import_specs(path.read_text(), path, functions):
        if kind == "from":
            if level == 0:
                if not (module_name or "").startswith(package):
                    continue
                anchor: list[str] = []
                module = (module_name or "").split(".")[1:]
            else:
                anchor = pkg[: len(pkg) - (level - 1)] if level > 1 else pkg
                module = module_name.split(".") if module_name else []
            base = ".".join([*anchor, *module])
            target = _module_file(base, package_dir)
            if target is not None:
                found.add(target)
            for name in names:  # "from . import io": io is a module
                sub = _module_file(".".join(p for p in (base, name) if p), package_dir)
                if sub is not None:
                    found.add(sub)
        else:
            for name in names:
                if name.startswith(f"{package}."):
                    target = _module_file(".".join(name.split(".")[1:]), package_dir)
                    if target is not None:
                        found.add(target)
    return found


def _packages(path: Path, package_dir: Path) -> set[Path]:
    """The ``__init__.py`` of every package ``path`` lies in (run when it is imported)."""
    found = set()
    for parent in path.parents:
        if parent != package_dir and package_dir not in parent.parents:
            break
        init = parent / "__init__.py"
        if init.is_file():
            found.add(init)
    return found


def _entry(entry: str, package_dir: Path) -> tuple[Path, frozenset[str] | None]:
    """``"module.py"`` or ``"module.py:f,g"`` as (file, functions or None for all)."""
    name, _, functions = entry.partition(":")
    path = package_dir / name
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such module of the package (entry {entry!r})")
    return path, (frozenset(functions.split(",")) if functions else None)


def import_closure(
    entries: tuple[str, ...], package_dir: Path, skip: frozenset[str] = frozenset()
) -> tuple[str, ...]:
    """The modules of the package in ``package_dir`` that ``entries`` run: the entries
    (``"module.py"``, or ``"sub/module.py:f,g"`` for the functions ``f``, ``g`` of a module,
    whose imports are followed at the module's top level and inside those functions and the
    module's functions they call only), every package module they import, directly or not,
    and the ``__init__.py`` of their packages, as sorted paths relative to ``package_dir``.
    A module reached by an import is followed whole; a module in ``skip`` (relative paths)
    is neither listed nor followed."""
    todo = [_entry(e, package_dir) for e in entries]
    whole: set[Path] = set()
    partial: dict[Path, frozenset[str]] = {}
    while todo:
        path, functions = todo.pop()
        if path in whole or not path.is_file():
            continue
        if str(path.relative_to(package_dir)) in skip:
            continue  # neither hashed nor followed
        if functions is None:
            whole.add(path)
        else:
            functions -= partial.get(path, frozenset())
            if not functions:
                continue
            partial[path] = partial.get(path, frozenset()) | functions
        found = _imports(path, package_dir, functions) | _packages(path, package_dir)
        todo.extend((p, None) for p in found)
    return tuple(sorted(str(p.relative_to(package_dir)) for p in whole | set(partial)))


# --------------------------------------------------------------------------- outside the package
def imported_names(path: str | Path, module: str, is_package: bool = False) -> set[str]:
    """The absolute names that module ``module`` (its file ``path``; ``is_package`` for an
    ``__init__.py``) imports anywhere in its code but under ``if TYPE_CHECKING:``: ``import
    a.b`` gives ``a`` and ``a.b``, ``from a import b`` gives ``a`` and ``a.b`` (``b`` may be
    a module), relative imports are resolved against ``module``'s package."""
    tree = ast.parse(Path(path).read_bytes(), filename=str(path))
    package = module if is_package else module.rpartition(".")[0]
    names: set[str] = set()

    def add(name: str) -> None:
        parts = name.split(".")
        names.update(".".join(parts[: i + 1]) for i in range(len(parts)))

    def relative(level: int, name: str | None) -> str:
        anchor = package.split(".") if package else []
        anchor = anchor[: len(anchor) - (level - 1)] if level > 1 else anchor
        if not anchor:  # beyond the top level: the import fails where it runs
            return ""
        return ".".join([*anchor, *([name] if name else [])])

    for node in _walk(tree.body):
        if isinstance(node, ast.Import):
            for alias in node.names:
                add(alias.name)
        elif isinstance(node, ast.ImportFrom):
            base = relative(node.level, node.module) if node.level else node.module or ""
            if not base:
                continue
            add(base)
            for alias in node.names:
                if alias.name != "*":
                    names.add(f"{base}.{alias.name}")
        elif isinstance(node, ast.Call):  # importlib.import_module("..."), __import__
            for level, name in dynamic_import(node) or []:
                target = relative(level, name) if level else name
                if target:
                    add(target)
    return names


def module_file(name: str) -> tuple[Path, bool] | None:
    """The file of the module ``name`` as the running interpreter would import it, with
    whether it is a package (``__init__``), found without importing anything (a submodule is
    looked up on its parent's path); None for a name that is no module (an attribute), a
    built-in or frozen module, or a namespace package."""
    parts = name.split(".")
    try:
        spec = importlib.util.find_spec(parts[0])  # a top-level name: nothing is imported
    except (ImportError, ValueError):
        return None
    for i in range(1, len(parts)):
        locations = spec.submodule_search_locations if spec is not None else None
        if not locations:
            return None
        spec = importlib.machinery.PathFinder.find_spec(".".join(parts[: i + 1]), list(locations))
    if spec is None or not spec.has_location or not spec.origin:
        return None
    origin = Path(spec.origin)
    return (origin, spec.submodule_search_locations is not None) if origin.is_file() else None


def environment_dirs() -> tuple[Path, ...]:
    """The folders of the pinned environment: the interpreter's standard library and the
    site-packages of the virtual environment (and of the installation it was made from)."""
    found: set[str] = set()
    for scheme_vars in ({}, {"base": sys.base_prefix, "platbase": sys.base_exec_prefix}):
        paths = sysconfig.get_paths(vars=scheme_vars or None)
        found.update(paths[k] for k in ("stdlib", "platstdlib", "purelib", "platlib"))
    found.update(site.getsitepackages())
    found.add(site.getusersitepackages())
    found.update(p for p in sys.path if Path(p).name in ("site-packages", "dist-packages"))
    return tuple(sorted({Path(p).resolve() for p in found if p}))


def outside_modules(
    modules: Iterable[tuple[str, Path, bool]], package: str, environment: Iterable[Path]
) -> tuple[dict[str, Path], set[str]]:
    """What code ``modules`` (name, file, is a package) of ``package`` run outside it and
    outside the pinned ``environment`` folders: every module they import, directly or through
    each other, whose file lies elsewhere (a user's own module on ``PYTHONPATH``, a module of
    the project tree), by name; and the names of ``package``'s modules those import.  Import
    statements anywhere in a module count, and so do ``importlib.import_module`` and
    ``__import__`` of a string literal; a module of ``modules`` or outside that imports by a
    form that cannot be followed is refused (:func:`refuse_unfollowable_imports`)."""
    env = tuple(environment)
    outside: dict[str, Path] = {}
    own: set[str] = set()
    todo = list(modules)
    seen: set[str] = set()
    while todo:
        name, path, is_package = todo.pop()
        if name in seen:
            continue
        seen.add(name)
        refuse_unfollowable_imports(path, name)
        for imported in sorted(imported_names(path, name, is_package)):
            top = imported.partition(".")[0]
            if top == package:
                if not name.startswith(f"{package}.") and name != package:
                    own.add(imported)
                continue
            if imported in outside or imported in seen:
                continue
            found = module_file(imported)
            if found is None:
                continue
            file = found[0].resolve()
            if any(file.is_relative_to(d) for d in env):
                continue
            outside[imported] = file
            if file.suffix == ".py":
                todo.append((imported, file, found[1]))
    return outside, own
