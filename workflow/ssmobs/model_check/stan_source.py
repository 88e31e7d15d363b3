"""The Stan source of the model check (:mod:`ssmobs.model_check.check`, step 2), read without
compiling: the ``parameters`` block declares ``(*param_names, x0, x)`` in this order, the
``data`` block ``T``, ``z`` and every parameter's prior bounds.
"""

from __future__ import annotations

import re
from pathlib import Path

from ..models import StateSpaceModel
from ..stan_backends.base import program_code


def _strip_comments(code: str) -> str:
    code = re.sub(r"/\*.*?\*/", " ", code, flags=re.S)
    return re.sub(r"(//|#).*", "", code)


def stan_block(code: str, name: str) -> str | None:
    """Body of the block ``name`` (e.g. ``parameters``; not ``transformed parameters``)."""
    code = _strip_comments(code)
    for match in re.finditer(rf"\b{name}\s*\{{", code):
        before = code[: match.start()].rstrip()
        if not before.endswith(("transformed", "generated")):
            break
    else:
        return None
    depth, start = 1, match.end()
    for i in range(start, len(code)):
        if code[i] == "{":
            depth += 1
        elif code[i] == "}":
            depth -= 1
            if depth == 0:
                return code[start:i]
    return None


def declared_names(block: str) -> list[str]:
    """Variable names declared in a Stan ``data`` or ``parameters`` block, in order."""
    names = []
    for stmt in block.split(";"):
        flat, prev = stmt, None
        while flat != prev:  # drop bounds <...>, sizes [...] and calls (...), innermost first
            prev, flat = flat, re.sub(r"<[^<>]*>|\[[^\[\]]*\]|\([^()]*\)", " ", flat)
        ids = re.findall(r"[A-Za-z_][A-Za-z0-9_]*", flat.split("=")[0])
        if len(ids) >= 2:  # a type and a name
            names.append(ids[-1])
    return names


def expected_parameters(model: StateSpaceModel) -> list[str]:
    """Stan parameters in Theta's order: Omega, then x0, then x."""
    return [*model.param_names, "x0", "x"]


def stan_source_problems(model: StateSpaceModel, stan_path: Path) -> list[str]:
    """Parameter names and order, and the data the Python side passes, read from the source."""
    if not stan_path.is_file():
        return [
            f"no Stan program {stan_path}: name an existing file, or none (without "
            f"stan/{model.slug}.stan the check takes the program generated from the model)"
        ]
    code = program_code(stan_path)  # with its #include files
    problems = []
    params = stan_block(code, "parameters")
    want = expected_parameters(model)
    if params is None:
        problems.append(f"{stan_path.name}: no parameters block found")
    else:
        got = declared_names(params)
        if got != want:
            problems.append(
                f"{stan_path.name}: the parameters block declares {got}, but the Python model "
                f"'{model.slug}' (param_names = {list(model.param_names)}) needs exactly {want} "
                f"in this order: Theta = (Omega, x0, x_1..x_T)"
            )
    data = stan_block(code, "data")
    declared = declared_names(data) if data is not None else []
    needed = ["T", "z"] + [f"{n}_{s}" for n in model.param_names for s in ("lower", "upper")]
    missing = [n for n in needed if n not in declared]
    if missing:
        problems.append(
            f"{stan_path.name}: the data block does not declare {missing}; the Python model "
            f"passes T, z and the flat prior bounds <name>_lower, <name>_upper of every "
            f"parameter (ssmobs.models.base.StateSpaceModel.stan_data), and the Stan program "
            f"must bound each parameter by them"
        )
    return problems
