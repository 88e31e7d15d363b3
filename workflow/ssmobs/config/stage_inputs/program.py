"""What rule build_stan_model reads (Sec. III.C): one model's program for one backend."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from ..blocks import stan_gradients

#: how the content key of a generated program starts
#: (:meth:`ssmobs.cache_keys.CacheKeys.stan_program`)
GENERATED_PREFIX = "generated-"


@dataclass(frozen=True)
class ProgramInputs:
    """Everything rule build_stan_model reads (Sec. III.C): the model and the backend that
    compiles its program (both name the marker's folder,
    :data:`~ssmobs.stage_table.PROGRAM_MARKER`), that backend with its Stan version, the
    program's content key and the gradient path of a hand-written program."""

    model: str
    #: the concrete backend's name (``native``, ``cmdstanpy``, ``pystan``)
    backend: str
    #: the backend with its Stan version (:func:`ssmobs.cache_keys.stan_identity`, e.g.
    #: ``native stanc3 v2.35.0 (Unix)``): another Stan builds another program
    stan_version: str
    #: the program's content (:meth:`ssmobs.cache_keys.CacheKeys.stan_program`):
    #: ``stan/<model>.stan`` with its includes, or ``generated-<digest>`` of what a program
    #: generated for a model without one is made of
    program: str
    #: ``autodiff`` or ``analytic`` (config key ``stan.gradients``) for a hand-written
    #: program; ``autodiff`` for a generated one, which is analytic whatever the key
    gradients: str

    @property
    def generated(self) -> bool:
        """Whether the program is generated (the model has no ``stan/<model>.stan``)."""
        return self.program.startswith(GENERATED_PREFIX)


def program_inputs(
    model: str,
    config: Mapping[str, Any],
    *,
    backend: str,
    stan_version: str,
    program: str,
) -> ProgramInputs:
    """The inputs of rule build_stan_model for ``model`` of the validated ``config``, built
    by ``backend`` (``stan_version``: its identity) from the program of content key
    ``program``."""
    generated = program.startswith(GENERATED_PREFIX)
    return ProgramInputs(
        model=str(model),
        backend=str(backend),
        stan_version=str(stan_version),
        program=str(program),
        gradients="autodiff" if generated else stan_gradients(config["stan"]),
    )


def program_payload(inputs: ProgramInputs) -> dict[str, Any]:
    """What the compiled program's key holds of ``inputs``, in the names it held before this
    object (so no program, nor what NUTS made with one, is made again): the backend's Stan
    (``backend``), the program (``stan``) and ``gradients`` where not ``autodiff``.  The model
    and the backend's name are the marker's folder, not its key."""
    payload = {"backend": inputs.stan_version, "stan": inputs.program}
    return payload if inputs.gradients == "autodiff" else {**payload, "gradients": inputs.gradients}
