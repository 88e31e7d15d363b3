"""Stan backends: native (our driver on httpstan's Stan sources, the embedded default),
cmdstanpy (when CmdStan is installed) and PyStan 3.

``get_backend(name)`` picks one by the config key ``stan.backend`` ("auto", "native",
"cmdstanpy", "pystan"); ``resolve_backend`` turns "auto" into the concrete name (cmdstanpy
when CmdStan is installed, else native); ``stan_file(slug)`` is the repository's
``stan/<slug>.stan``.  All backends take the data dict of
:meth:`ssmobs.models.base.StateSpaceModel.stan_data`, return
:class:`~ssmobs.stan_backends.base.Draws` and give the same draws for the same seed.

The backend modules import their Stan library lazily, so choosing one never needs the other.
"""

from __future__ import annotations

import os
from pathlib import Path

from .base import (
    SAMPLER_COLUMNS,
    BackendError,
    Draws,
    SamplerSettings,
    SamplingError,
    StanBackend,
)

#: values accepted for the config key ``stan.backend``
BACKEND_NAMES: tuple[str, ...] = ("auto", "native", "cmdstanpy", "pystan")

#: repository directory holding the Stan programs (workflow/ssmobs/../../stan)
STAN_DIR = Path(__file__).resolve().parents[3] / "stan"


def have_cmdstan() -> bool:
    """True when cmdstanpy finds a CmdStan installation that has ``bin/stanc``.

    cmdstanpy looks at ``$CMDSTAN`` (if set and non-empty), else at the newest
    ``~/.cmdstan/cmdstan-*``; it only checks the directory and its makefile, so the
    compiler binary is checked here as well.
    """
    try:
        import cmdstanpy
    except ImportError:  # pragma: no cover - cmdstanpy is a dependency
        return False
    try:
        path = cmdstanpy.cmdstan_path()
    except ValueError:
        return False
    stanc = Path(path) / "bin" / ("stanc.exe" if os.name == "nt" else "stanc")
    return stanc.is_file()


def resolve_backend(name: str = "auto") -> str:
    """The concrete backend name for the config value ``stan.backend``.

    ``auto`` gives cmdstanpy when CmdStan is installed (:func:`have_cmdstan`), else native.
    Unknown names raise ValueError.
    """
    if name not in BACKEND_NAMES:
        raise ValueError(
            f"stan.backend: unknown value {name!r}; choose one of {list(BACKEND_NAMES)}"
        )
    if name == "auto":
        return "cmdstanpy" if have_cmdstan() else "native"
    return name


def get_backend(name: str = "auto") -> StanBackend:
    """The backend for the config value ``stan.backend`` (see :func:`resolve_backend`).

    ``cmdstanpy`` without CmdStan and unknown names raise ValueError.
    """
    name = resolve_backend(name)
    if name == "native":
        from .native import NativeBackend

        return NativeBackend()
    if name == "cmdstanpy":
        if not have_cmdstan():
            cmdstan_env = os.environ.get("CMDSTAN")
            where = (
                f"$CMDSTAN={cmdstan_env!r} is not a CmdStan installation with bin/stanc"
                if cmdstan_env
                else "$CMDSTAN is unset and ~/.cmdstan has no cmdstan-*"
            )
            raise ValueError(
                f"stan.backend: 'cmdstanpy' needs a CmdStan installation, but none was found "
                f"({where}). Install CmdStan with `python -m cmdstanpy.install_cmdstan` (needs "
                f"network access to GitHub and a C++ toolchain) or point $CMDSTAN at an "
                f"existing installation; or set stan.backend to 'native' (embedded, no CmdStan "
                f"needed) or 'auto' (cmdstanpy when CmdStan is there, else native)."
            )
        from .cmdstanpy import CmdStanPyBackend

        return CmdStanPyBackend()
    from .pystan import PyStanBackend

    return PyStanBackend()


def has_stan_file(slug: str) -> bool:
    """The repository holds a hand-written program ``stan/<slug>.stan`` for the model (else
    the workflow generates one: :func:`ssmobs.nuts.stan_program.stan_program`)."""
    return "/" not in slug and "\\" not in slug and (STAN_DIR / f"{slug}.stan").is_file()


def stan_file(slug: str) -> Path:
    """The Stan program ``stan/<slug>.stan`` of the repository (FileNotFoundError if absent)."""
    path = STAN_DIR / f"{slug}.stan"
    if "/" in slug or "\\" in slug or not path.is_file():
        known = sorted(p.stem for p in STAN_DIR.glob("*.stan"))
        raise FileNotFoundError(
            f"no Stan program for model {slug!r} at {path}; programs in {STAN_DIR}: {known}"
        )
    return path


__all__ = [
    "BACKEND_NAMES",
    "BackendError",
    "Draws",
    "SAMPLER_COLUMNS",
    "STAN_DIR",
    "SamplerSettings",
    "SamplingError",
    "StanBackend",
    "get_backend",
    "has_stan_file",
    "have_cmdstan",
    "resolve_backend",
    "stan_file",
]
