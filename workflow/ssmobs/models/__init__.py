"""State space models by slug, found automatically.

A model is one module ``workflow/ssmobs/models/<slug>.py`` that defines exactly one
:class:`~ssmobs.models.base.StateSpaceModel` subclass whose ``slug`` is the file name, plus
one Stan program ``stan/<slug>.stan`` (see ``docs/your-own-model.md``).  Every such module
is imported at the first lookup in :data:`MODELS` and checked by
:func:`definition_problems`; a module that breaks the contract stops the lookup with one
:class:`ModelDefinitionError` naming the file and what is wrong, at the first lookup
(before any work is done).  Modules whose name starts with ``_`` and the package's own
modules (``base``, ``log_posterior``, ``symmetries``, ``propriety``, and the model's check of
itself: ``check_cases``, ``self_check``) are not models.
"""

from __future__ import annotations

import importlib
import importlib.util
import inspect
import keyword
import re
from collections.abc import Iterator, Mapping
from pathlib import Path
from types import ModuleType

from .base import PRIOR_VARIANTS, ModelDefinitionError, PriorBounds, StateSpaceModel

#: directory searched for model modules
MODELS_DIR = Path(__file__).resolve().parent

#: modules of this package that are not models
INTERNAL_MODULES: frozenset[str] = frozenset(
    {"base", "log_posterior", "symmetries", "propriety", "check_cases", "self_check"}
)

#: class attributes every model sets (see :class:`StateSpaceModel`)
REQUIRED_ATTRIBUTES: tuple[str, ...] = (
    "slug",
    "title",
    "obs_dim",
    "state_dim",
    "param_names",
    "default_prior",
    "allowed_priors",
)

#: methods every model implements
REQUIRED_METHODS: tuple[str, ...] = ("obs_term", "trans_term", "simulate")

#: names a parameter may not take: Theta's states and the Stan data of every program
RESERVED_NAMES: frozenset[str] = frozenset({"x0", "x", "z", "T"})

_IDENTIFIER = re.compile(r"^[A-Za-z][A-Za-z0-9_]*$")


def definition_problems(cls: type[StateSpaceModel], expected_slug: str) -> list[str]:
    """Problems of a model class (empty list when it fulfils the contract).

    Checks the required attributes and methods, their types, that ``slug`` equals the
    module's file name ``expected_slug``, that parameter names are unique identifiers usable
    in Stan, and that ``default_prior`` / ``allowed_priors`` name exactly the parameters
    with known variants.
    """
    problems: list[str] = []
    missing = [a for a in REQUIRED_ATTRIBUTES if not hasattr(cls, a)]
    if missing:
        problems.append(f"missing required class attribute(s) {missing}")
    not_implemented = [
        m for m in REQUIRED_METHODS if getattr(cls, m, None) is getattr(StateSpaceModel, m)
    ]
    if not_implemented:
        problems.append(
            f"missing required method(s) {not_implemented} (see ssmobs.models.base.StateSpaceModel)"
        )
    if missing:
        return problems
    if cls.slug != expected_slug:
        problems.append(
            f"slug = {cls.slug!r} but the file is {expected_slug}.py; a model's slug "
            f"is its file name (set slug = {expected_slug!r})"
        )
    for dim in ("obs_dim", "state_dim"):
        value = getattr(cls, dim)
        if not isinstance(value, int) or isinstance(value, bool) or value < 1:
            problems.append(f"{dim} = {value!r} must be an integer >= 1")
    names = cls.param_names
    if not isinstance(names, tuple) or not names or not all(isinstance(n, str) for n in names):
        problems.append(f"param_names = {names!r} must be a non-empty tuple of strings")
        return problems
    bad = [
        n
        for n in names
        if not _IDENTIFIER.match(n)
        or keyword.iskeyword(n)
        or n in RESERVED_NAMES
        or n.endswith(("_lower", "_upper"))
    ]
    if bad:
        problems.append(
            f"param_names {list(bad)} are not allowed: use identifiers (letters, "
            f"digits, _) other than {sorted(RESERVED_NAMES)} and not ending in "
            f"_lower/_upper"
        )
    if len(set(names)) != len(names):
        problems.append(f"param_names = {names!r} lists a name twice")
    for attr in ("default_prior", "allowed_priors"):
        mapping = getattr(cls, attr)
        if not isinstance(mapping, dict) or set(mapping) != set(names):
            keys = sorted(mapping) if isinstance(mapping, dict) else mapping
            problems.append(
                f"{attr} must have exactly one entry per parameter {list(names)}, got {keys!r}"
            )
            return problems
    allowed_ok = True
    for name in names:
        allowed = cls.allowed_priors[name]
        if isinstance(allowed, str) or not all(v in PRIOR_VARIANTS for v in allowed):
            allowed_ok = False
            problems.append(
                f"allowed_priors[{name!r}] = {allowed!r} must be a tuple of "
                f"variants from {list(PRIOR_VARIANTS)}"
            )
    if allowed_ok:
        # a variant from allowed_priors, or an interval (lower, upper) (.inf allowed)
        problems += cls.default_prior_problems()
    for attr in ("unit_interval_params", "positive_params"):
        unknown = [n for n in getattr(cls, attr) if n not in names]
        if unknown:
            problems.append(f"{attr} names {unknown}, which are not in param_names {list(names)}")
    return problems


def model_files(directory: Path = MODELS_DIR) -> list[Path]:
    """The model modules of ``directory``: ``*.py`` except ``_*`` and the package's own."""
    return sorted(
        p
        for p in Path(directory).glob("*.py")
        if not p.stem.startswith("_") and p.stem not in INTERNAL_MODULES
    )


def _import(path: Path, directory: Path) -> ModuleType:
    if Path(directory).resolve() == MODELS_DIR:
        return importlib.import_module(f"{__name__}.{path.stem}")
    name = f"_ssmobs_user_models_{abs(hash(str(directory)))}.{path.stem}"
    spec = importlib.util.spec_from_file_location(name, path)
    assert spec is not None and spec.loader is not None, f"{path} is not a .py file"
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _model_class(path: Path, module: ModuleType) -> type[StateSpaceModel]:
    classes = [
        obj
        for obj in vars(module).values()
        if inspect.isclass(obj)
        and issubclass(obj, StateSpaceModel)
        and obj is not StateSpaceModel
        and obj.__module__ == module.__name__
    ]
    if len(classes) != 1:
        found = [c.__name__ for c in classes]
        raise ModelDefinitionError(
            f"model module {path}: must define exactly one subclass of "
            f"ssmobs.models.base.StateSpaceModel, found {found or 'none'}"
        )
    return classes[0]


def _discover(directory: Path) -> tuple[dict[str, StateSpaceModel], dict[str, list[str]]]:
    """The models of ``directory`` that fulfil the contract, by slug, and the problems of
    the others by the slug their file name gives them (see :func:`discover_models`)."""
    problems: dict[str, list[str]] = {}
    found: list[tuple[Path, type[StateSpaceModel]]] = []
    for path in model_files(directory):
        try:
            module = _import(path, directory)
            found.append((path, _model_class(path, module)))
        except ModelDefinitionError as err:
            problems.setdefault(path.stem, []).append(str(err))
        except Exception as err:  # noqa: BLE001 - reported with the file it came from
            why = " ".join(f"{type(err).__name__}: {err}".split())  # one line
            problems.setdefault(path.stem, []).append(f"model module {path}: import failed: {why}")
    by_slug: dict[str, list[tuple[Path, type[StateSpaceModel]]]] = {}
    for path, cls in found:
        by_slug.setdefault(getattr(cls, "slug", path.stem), []).append((path, cls))
    for slug, owners in by_slug.items():
        if len(owners) > 1:
            where = " and ".join(f"{p.name} ({c.__name__})" for p, c in owners)
            for p, _ in owners:
                problems.setdefault(p.stem, []).append(
                    f"slug {slug!r} is used twice: by {where}; each model needs its own "
                    f"slug, equal to its file name"
                )
    for path, cls in found:
        if len(by_slug[getattr(cls, "slug", path.stem)]) > 1:
            continue
        for msg in definition_problems(cls, path.stem):
            problems.setdefault(path.stem, []).append(
                f"model module {path} ({cls.__name__}): {msg}"
            )
    models = {cls.slug: cls() for path, cls in found if path.stem not in problems}
    return models, problems


def discover_models(directory: Path = MODELS_DIR) -> dict[str, StateSpaceModel]:
    """Import every model module of ``directory`` and return its models by slug.

    Raises :class:`ModelDefinitionError` (one message listing every problem, each naming its
    file) when a module fails to import, does not define exactly one model class, breaks the
    contract of :func:`definition_problems`, or declares a slug that another module uses.
    """
    models, problems = _discover(directory)
    if problems:
        listed = list(dict.fromkeys(m for msgs in problems.values() for m in msgs))
        raise ModelDefinitionError("invalid model definition(s):\n  - " + "\n  - ".join(listed))
    return models


class _Registry(Mapping[str, StateSpaceModel]):
    """The models of :data:`MODELS_DIR` by slug, discovered on first use (so that importing
    this package never fails).  A module that breaks the contract (a syntax error, a missing
    attribute) stops only its own lookup, with one line naming its file
    (:class:`ModelDefinitionError`); the other models are found and listed as usual, so a
    config that does not use it runs."""

    def __init__(self) -> None:
        self._models: dict[str, StateSpaceModel] | None = None
        self._problems: dict[str, list[str]] = {}

    def _load(self) -> dict[str, StateSpaceModel]:
        if self._models is None:
            self._models, self._problems = _discover(MODELS_DIR)
        return self._models

    def __getitem__(self, slug: str) -> StateSpaceModel:
        models = self._load()
        if slug in self._problems and slug not in models:
            what = "; ".join(self._problems[slug])
            raise ModelDefinitionError(
                f"{what} (fix the module, or move it out of {MODELS_DIR}; configs that do "
                f"not use model {slug!r} run)"
            )
        return models[slug]

    def __iter__(self) -> Iterator[str]:
        return iter(self._load())

    def __len__(self) -> int:
        return len(self._load())


MODELS: Mapping[str, StateSpaceModel] = _Registry()


def get_model(slug: str) -> StateSpaceModel:
    """The model with this slug; ValueError listing the known slugs otherwise."""
    try:
        return MODELS[slug]
    except KeyError:
        raise ValueError(
            f"unknown model '{slug}'; known models: {sorted(MODELS)} (a model "
            f"'{slug}' would be the module workflow/ssmobs/models/{slug}.py)"
        ) from None


__all__ = [
    "MODELS",
    "PRIOR_VARIANTS",
    "ModelDefinitionError",
    "PriorBounds",
    "StateSpaceModel",
    "definition_problems",
    "discover_models",
    "get_model",
]
