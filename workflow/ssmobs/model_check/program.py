"""Which generated Stan program the model check runs (:mod:`ssmobs.model_check.check`, steps 3
and 4), and who writes it.

In the workflow, rule build_stan_model is the one job that writes a generated program (the
analytic one of a hand-written ``stan/<model>.stan``, or a whole program for a model without
one: :func:`ssmobs.nuts.stan_program.stan_program`); its marker names the files it compiled
(``program_file``, ``header_file``), and rule check_model_stan, which has that marker as an
input, reads them there (:func:`built_program_files`) and writes nothing.  The check is as
strong either way: the files must hold exactly the texts generated from the model now (their
digest is the key of the folder :func:`ssmobs.nuts.analytic_program.analytic_program_files`
names), wherever the program cache lies.

Without a build job the check writes the program itself (:func:`checked_program` without a
marker): the command line ``python -m ssmobs.model_check`` for a user's own model, a direct
call of :func:`~ssmobs.model_check.check.check_model`, and rule check_model_stan when the
sampling backend is not the native driver (its input then holds no marker of the native
build the check evaluates with).  The written bytes are the build job's (content-keyed,
written once and atomically), so the two never disagree.
"""

from __future__ import annotations

from pathlib import Path

from ..models import StateSpaceModel
from ..nuts.analytic_program import AnalyticProgram, analytic_program_files, write_analytic_program
from ..nuts.stan_program import built_program

#: a Stan program and its C++ header (None: a program without one)
ProgramFiles = tuple[Path, Path | None]


def built_program_files(marker: str | Path) -> ProgramFiles:
    """The Stan program and C++ header (or None) that rule build_stan_model compiled, as its
    marker names them (:func:`ssmobs.nuts.stan_program.built_program`)."""
    _, program, header = built_program(marker)
    return program, header


def checked_program(
    model: StateSpaceModel, stan_file: Path | None, built: ProgramFiles | None
) -> AnalyticProgram:
    """The generated program of ``model`` the check runs: from its Stan program ``stan_file``
    (the analytic one, which keeps the hand-written statements as its autodiff twin) or, for
    None, a whole generated program.  ``built``: the files rule build_stan_model wrote and
    compiled (:func:`built_program_files`), read as they are; None: written here (see the
    module docstring for who does that).  ValueError in one line where the build job's files
    do not hold the program generated from the model now."""
    if built is None:
        return write_analytic_program(model, stan_file)
    program, header = built
    if header is None:
        raise ValueError(
            f"{program}: its build job compiled it without the C++ header of generated "
            f"gradients, but model '{model.slug}' runs a generated program here"
        )
    found = AnalyticProgram(program, header)
    expected = analytic_program_files(model, stan_file)
    if expected.stan_file.parent.name != f"{model.slug}-{found.digest}":
        raise ValueError(
            f"{program}: the program its build job compiled is not the one generated from "
            f"model '{model.slug}' now (expected the files of {expected.stan_file.parent.name})"
        )
    return found


def same_program(stan_file: Path, built: ProgramFiles) -> None:
    """ValueError in one line unless ``built`` (a build job's files) is the hand-written
    ``stan_file`` itself, by content, with no C++ header: what NUTS runs with autodiff."""
    program, header = built
    if header is not None or program.read_bytes() != stan_file.read_bytes():
        raise ValueError(
            f"{program}: the program its build job compiled is not {stan_file} "
            f"(the program NUTS runs with Stan's autodiff gradients)"
        )
