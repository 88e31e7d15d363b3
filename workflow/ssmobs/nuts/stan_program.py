"""Which Stan program NUTS runs for a model (Sec. III.C): the hand-written
``stan/<model>.stan``, or the program with the generated analytic gradients
(:mod:`ssmobs.nuts.analytic_program`).  :func:`stan_program` writes a generated program into
the cache (rule build_stan_model's job; the NUTS jobs run the program its marker names);
:func:`planned_stan_program` only says where it lies (the planning of a run, which writes
nothing).
"""

from __future__ import annotations

from pathlib import Path

from .. import io
from ..models import get_model
from ..stan_backends import has_stan_file, stan_file
from .analytic_program import analytic_program_files, write_analytic_program


def stan_program(model: str, gradients: str = "autodiff") -> tuple[Path, Path | None]:
    """The Stan program NUTS runs for ``model`` and its C++ header (config key
    ``stan.gradients``): ``stan/<model>.stan`` itself for ``autodiff``; for ``analytic`` the
    program whose model block calls the log density and gradient generated from the model's
    terms (:mod:`ssmobs.nuts.analytic_gradients`), its own statements kept beside for the
    model check (:func:`~ssmobs.nuts.analytic_program.analytic_stan_code`), in the cache.  A
    model without ``stan/<model>.stan`` gets a whole generated program (always analytic:
    parameters and bounds from the model,
    :func:`~ssmobs.nuts.analytic_program.generated_stan_code`);
    ValueError (one line) for a model whose support constraints it cannot express."""
    return _program(model, gradients, write=True)


def planned_stan_program(model: str, gradients: str = "autodiff") -> tuple[Path, Path | None]:
    """:func:`stan_program`'s answer without writing a generated program (its files may not
    be there yet)."""
    return _program(model, gradients, write=False)


def _program(model: str, gradients: str, *, write: bool) -> tuple[Path, Path | None]:
    if gradients not in ("autodiff", "analytic"):  # a value from config.blocks.stan_gradients
        raise ValueError(f"stan.gradients: {gradients!r}; allowed: autodiff, analytic")
    make = write_analytic_program if write else analytic_program_files
    if not has_stan_file(model):
        generated = make(get_model(model), None)
        return generated.stan_file, generated.header
    path = stan_file(model)
    if gradients == "autodiff":
        return path, None
    generated = make(get_model(model), path)
    return generated.stan_file, generated.header


def built_program(marker: str | Path) -> tuple[str, Path, Path | None]:
    """The backend, the Stan program and its C++ header (or None) that rule build_stan_model
    compiled, as its marker names them (the one reader of a marker, for the NUTS batches and
    the model check); FileNotFoundError in one line where one is gone (a cleared program
    cache: the workflow removes such a marker before it builds its DAG,
    :func:`ssmobs.housekeeping.orphaned_program_markers`, so its build job writes it again)."""
    built = io.read_json(marker, required=["backend", "program_file", "header_file"])
    program = Path(built["program_file"])
    header = None if built["header_file"] is None else Path(built["header_file"])
    for path in (program, header):
        if path is not None and not path.is_file():
            raise FileNotFoundError(
                f"{path}: the Stan program that {marker} names is gone (was the program cache "
                f"cleared?); run the workflow again: it builds the program first"
            )
    return str(built["backend"]), program, header
