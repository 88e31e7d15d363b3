"""Content keys of the workflow's cached outputs: every output is keyed by what determines it.

Each stage's outputs live under ``results/.../<key>/``, where ``<key>`` is 12 hex digits of
a SHA-256 over everything that determines them (the rule of the cache):

- the config values the stage reads (a scenario's model, Omega, x0, T, K, method, seed,
  prior, the stage's settings block),
- the keys of the stage's inputs (so a change upstream moves every output downstream),
- the code: the model's module with every module it imports outside the pinned
  environment (the package's, the project tree's, a user's own), its Stan program, and
  the source of the package modules the stage runs (:data:`ssmobs.stage_table.STAGES`:
  its glue in :mod:`ssmobs.stages`, closed over its imports inside the package by
  :func:`ssmobs.stage_code.module_closure`), so an edit of a log-density term
  or of a stage's numerics gives new keys and a recomputation, never an old result; an
  edit of code a stage does not run (a figure's glue) leaves its keys alone,
- the numerical kernels every job computes with (:data:`ssmobs.kernels.SETTINGS_ID`), in
  every key: the same key means the same bits on any x86-64 CPU with AVX2.

A key path that exists holds exactly what its key describes, whatever the files' times
and whatever ``.snakemake/`` holds; a path that does not exist is computed.  Editing the
config back to an earlier state finds the earlier outputs again.  Every key's payload is
written beside nothing and hashed only; :meth:`CacheKeys.describe` returns it for a person
(``python -m ssmobs.cache_keys --configfile ...`` prints them).
"""

from __future__ import annotations

import functools
import json
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from . import kernels
from .config.maps import cell_entries
from .config.stage_inputs import inputs_payload, map_cell_inputs, map_cells_inputs
from .stage_code import (
    PACKAGE_DIR,
    REPO_DIR,
    code_digest,
    digest,
    file_digest,
    model_code,
)
from .stage_table import NATIVE_DRIVER, NATIVE_SHADOW_HEADERS, PROGRAM_MARKER, STAGES
from .stan_backends.base import program_digest


# --------------------------------------------------------------------------- the keys
def _at(stage: str, at: Mapping[str, int]) -> dict[str, int]:
    """Of ``at``, what ``stage`` is keyed by (an upstream stage keyed per K, or not)."""
    return {k: v for k, v in at.items() if k in STAGES[stage].per}


class UnknownKeyError(KeyError):
    """A keyed path was asked for whose key the current config does not produce."""


def stan_identity(backend: str) -> str:
    """The Stan backend a config names (``auto`` resolved) with its Stan version, as the NUTS
    records name it (:func:`ssmobs.nuts.record_cache.backend_identity`, e.g. ``native stanc3
    v2.35.0 (Unix)``): part of the compiled programs' keys, so another Stan recomputes them
    and all after them.  ValueError or BackendError where that backend cannot start here."""
    from .nuts.record_cache import backend_identity
    from .stan_backends import get_backend

    return backend_identity(get_backend(backend))


class CacheKeys:
    """Every key of one validated config (see the module docstring), with a lookup from
    (kind, name, key) back to what it describes, for the rules' wildcards.  ``backend``: the
    sampling backend's :func:`stan_identity`; ``check_backend``: that of the backend the
    model check evaluates Stan's log density with (the native driver)."""

    def __init__(
        self,
        config: Mapping[str, Any],
        backend: str,
        repo: Path = REPO_DIR,
        package_dir: Path = PACKAGE_DIR,
        check_backend: str = "native",
        backend_name: str | None = None,
    ) -> None:
        self.config = config
        self.backend = backend
        #: the concrete backend's name (``native``, ...; by default ``backend`` itself)
        self.backend_name = backend if backend_name is None else backend_name
        self.check_backend = check_backend
        self.repo = Path(repo)
        self.package_dir = Path(package_dir)
        self.scenarios = {sc["name"]: sc for sc in config["scenarios"]}
        self.k_selections = {ks["name"]: ks for ks in config["k_selection"]}
        self._payloads: dict[str, dict[str, Any]] = {}
        self._lookup: dict[tuple[str, str, str], dict[str, Any]] = {}

    @classmethod
    def for_backend(cls, config: Mapping[str, Any], backend: str, **kw: Any) -> CacheKeys:
        """The keys of ``config`` sampled with ``backend`` (a config value): its
        :func:`stan_identity`, and the native driver's for the model check."""
        native = stan_identity("native")
        sampling = native if backend == "native" else stan_identity(backend)
        return cls(config, sampling, check_backend=native, backend_name=backend, **kw)

    # ------------------------------------------------------------------ helpers
    @functools.cache  # noqa: B019 - one object per parse of the workflow
    def code(self, stage: str) -> dict[str, str]:
        return code_digest(stage, self.package_dir)

    @functools.cache  # noqa: B019
    def model_code(self, model: str) -> dict[str, str]:
        """The model's Python module and the package modules it runs, directly or not (a
        helper ``models/_*.py``, a model it subclasses), by :func:`model_closure`, and every
        module outside the package and the pinned environment they import, directly or
        not (:func:`outside_code`), each by its :func:`syntax_digest` (a comment-only edit
        reruns nothing; its Stan program keys what it determines: :meth:`stan_program`)."""
        return model_code(model, self.package_dir)

    def stan_program(self, model: str) -> str:
        """The model's Stan program with its ``#include`` files; for a model without one,
        what its generated program is made of (:func:`ssmobs.nuts.stan_program.stan_program`):
        the model's code, the generator's format and SymPy's version (the generator's own
        code is in the stages' code keys)."""
        path = self.repo / "stan" / f"{model}.stan"
        if path.is_file():
            return program_digest(path)
        import sympy

        from .nuts.analytic_gradients import GENERATOR_VERSION

        payload = {
            "generated": GENERATOR_VERSION,
            "sympy": sympy.__version__,
            "model_code": self.model_code(model),
        }
        return "generated-" + digest(payload)

    def _key(self, kind: str, name: str, payload: dict[str, Any], **about: Any) -> str:
        # every output depends on the fixed numerical kernels (ssmobs/kernels.py)
        payload = {**payload, "kernels": kernels.SETTINGS_ID}
        key = digest(payload)
        self._payloads[f"{kind}:{name}:{key}"] = payload
        self._lookup[(kind, name, key)] = about
        return key

    def lookup(self, kind: str, name: str, key: str) -> dict[str, Any]:
        """What key ``key`` of ``kind`` for ``name`` describes (e.g. ``{"K": 300}``);
        raises :class:`UnknownKeyError` when the current config does not produce it."""
        try:
            return self._lookup[(kind, name, key)]
        except KeyError:
            raise UnknownKeyError(
                f"{kind} key {key} of {name!r} is not one the current config produces "
                f"(an output of an earlier config was asked for by its path)"
            ) from None

    def describe(self) -> dict[str, dict[str, Any]]:
        """Every key computed so far with its payload (what it is keyed by)."""
        return dict(self._payloads)

    # ------------------------------------------------------------------ stages
    @functools.cached_property
    def design_inputs(self) -> Any:
        """What rule design_disturbances reads
        (:class:`~ssmobs.config.stage_inputs.DesignSetsInputs`), the design key's content."""
        build = STAGES["design"].inputs
        assert build is not None
        return build(self.config)

    @functools.cached_property
    def design(self) -> str:
        """The design sets' key (Sec. III.A): their inputs (:attr:`design_inputs`) and code;
        q, K, method, seed are in the file name.  :meth:`lookup` of ``("design", "shared",
        key)`` gives ``{"inputs": ...}``."""
        entry, inputs = STAGES["design"], self.design_inputs
        assert entry.payload is not None
        payload = {**entry.payload(inputs), "code": self.code("design")}
        return self._key("design", "shared", payload, inputs=inputs)

    def has_stan_file(self, model: str) -> bool:
        """Whether ``model`` has a hand-written ``stan/<model>.stan`` (else its program is
        generated from its Python module)."""
        return (self.repo / "stan" / f"{model}.stan").is_file()

    def check_model(self, name: str, stan: bool = False) -> str:
        """The model check at a scenario's true values: the Python model alone (gates the
        design trajectories) or against the Stan program (gates the NUTS runs).  Keyed by
        its inputs (:class:`~ssmobs.config.stage_inputs.ModelCheckInputs`, of stage
        ``check_model`` or ``check_model_stan``): their case
        (:func:`~ssmobs.config.stage_inputs.check_case`'s dict) with the model's code and
        the check's; against Stan, the program, the check backend's Stan and the native
        driver; a gradient path other than autodiff, with our headers.  Every field of the
        inputs is in the payload, which is the one hashed before the inputs object."""
        stage = "check_model_stan" if stan else "check_model"
        inputs = self.inputs(stage, name)
        payload: dict[str, Any] = {
            "case": inputs.case_config,
            "model_code": self.model_code(inputs.model),
            "code": self.code(stage),
        }
        # with analytic gradients the check compares them with Stan's autodiff as well
        gradients = {} if inputs.gradients == "autodiff" else {"gradients": inputs.gradients}
        if inputs.against_stan:
            # the check runs the program in the native driver's log-density mode, whatever
            # backend samples: keyed by the program, that backend's Stan and the driver
            payload["stan"] = self.stan_program(inputs.model)
            payload["check_backend"] = self.check_backend
            payload["driver"] = file_digest(self.package_dir / NATIVE_DRIVER)
            if gradients or not self.has_stan_file(inputs.model):
                # ... and the sampler's gradient, through our headers (--sampler-gradient)
                payload["shadow_headers"] = {
                    h: file_digest(self.package_dir / h) for h in NATIVE_SHADOW_HEADERS
                }
        return self._key(stage, name, {**payload, **gradients})

    def trajectories(self, name: str, K: int | None = None) -> str:
        """The design trajectories' key at K (the scenario's own K by default;
        :class:`~ssmobs.config.stage_inputs.TrajectoriesInputs`)."""
        K = int(self.scenarios[name]["K"] if K is None else K)
        return self.stage_key("trajectories", name, K=K)

    @functools.cache  # noqa: B019
    def inputs(self, stage: str, name: str, **at: int) -> Any:
        """The frozen inputs object of ``stage`` for scenario ``name`` (``at``: K, for a
        stage keyed per K): its builder in :data:`~ssmobs.stage_table.STAGES` given the
        scenario's entry, the config and the paths of the keyed outputs it reads at the
        same K (which carry their keys)."""
        entry = STAGES[stage]
        assert entry.inputs is not None, f"stage {stage} has no inputs object yet"
        reads: dict[str, Any] = {
            kw: STAGES[up].read_path(name, getattr(self, up)(name, **_at(up, at)), output)
            for kw, (up, output) in entry.reads.items()
        }
        for shared in entry.shared:
            value = getattr(self, shared)
            reads[shared] = value(name) if callable(value) else value
        reads.update({per: at[per] for per in entry.builder_per})
        own = self.k_selections[name] if entry.of == "k_selection" else self.scenarios[name]
        return entry.inputs(own, self.config, **reads)

    def stage_key(self, stage: str, name: str, **at: int) -> str:
        """The key of a stage with an inputs object: its content and the stage's code (and
        the model's, where the stage runs the model)."""
        inputs = self.inputs(stage, name, **at)
        payload = {"inputs": inputs_payload(inputs), "code": self.code(stage)}
        if STAGES[stage].runs_model:
            payload["model_code"] = self.model_code(inputs.model)
        return self._key(stage, name, payload, **at)

    def joint_map(self, name: str) -> str:
        """The joint MAP's key (:class:`~ssmobs.config.stage_inputs.JointMapInputs`)."""
        return self.stage_key("joint_map", name)

    def program_marker(self, name: str) -> str:
        """The marker of scenario ``name``'s compiled program (rule build_stan_model's
        output, :data:`~ssmobs.stage_table.PROGRAM_MARKER`) for this run's backend
        (:attr:`backend_name`)."""
        model = self.scenarios[name]["model"]
        return PROGRAM_MARKER.format(
            backend=self.backend_name, model=model, key=self.program(model)
        )

    def own_program(self, name: str) -> bool:
        """Whether scenario ``name``'s model has a hand-written ``stan/<model>.stan`` (else
        NUTS runs its generated program)."""
        return self.has_stan_file(self.scenarios[name]["model"])

    @functools.cache  # noqa: B019
    def program_inputs(self, model: str) -> Any:
        """What rule build_stan_model reads for ``model``
        (:class:`~ssmobs.config.stage_inputs.ProgramInputs`): this run's backend
        (:attr:`backend_name`) with its Stan version, the program (:meth:`stan_program`) and
        the gradient path of a hand-written one."""
        build = STAGES["program"].inputs
        assert build is not None
        return build(
            model,
            self.config,
            backend=self.backend_name,
            stan_version=self.backend,
            program=self.stan_program(model),
        )

    def program(self, model: str) -> str:
        """The compiled-program marker's key of ``model``: its inputs
        (:meth:`program_inputs`: the backend's Stan version, so another Stan gives new
        programs, records and everything after them; the program; analytic gradients) with
        the build's code and, for analytic gradients, the model's terms they are generated
        from.  :meth:`lookup` of ``("program", model, key)`` gives ``{"inputs": ...}``, what
        the rule passes."""
        entry, inputs = STAGES["program"], self.program_inputs(model)
        assert entry.payload is not None
        payload = {**entry.payload(inputs), "code": self.code("program")}
        if inputs.gradients != "autodiff":
            payload["model_code"] = self.model_code(model)
        return self._key("program", model, payload, inputs=inputs)

    def nuts_records(self, name: str) -> str:
        """The NUTS records' key (:class:`~ssmobs.config.stage_inputs.NutsRecordsInputs`):
        everything that determines a trajectory's record, not the thresholds of the
        convergence checks (the batch tables apply them to the stored diagnostics)."""
        return self.stage_key("nuts_records", name)

    def nuts_batches(self, name: str, batch_size: int) -> str:
        """The NUTS batch tables' key for batches of ``batch_size``
        (:class:`~ssmobs.config.stage_inputs.NutsBatchesInputs`)."""
        return self.stage_key("nuts_batches", name, batch_size=int(batch_size))

    def gather(self, name: str, batch_size: int) -> str:
        """The gathered NUTS results' key for batches of ``batch_size``
        (:class:`~ssmobs.config.stage_inputs.GatherInputs`)."""
        return self.stage_key("gather", name, batch_size=int(batch_size))

    def exact(self, name: str, K: int) -> str:
        """The exact stage's key at K trajectories
        (:class:`~ssmobs.config.stage_inputs.ExactInputs`)."""
        return self.stage_key("exact", name, K=int(K))

    def k_selection_points(self, ksel: str) -> str:
        """Each point V_{K_i} of one k_selection entry (Sec. IV.A), cached one file per K_i
        and grid: what every point of its scenario reads
        (:class:`~ssmobs.config.stage_inputs.KSelectionPointsInputs`), the model's code and
        the points' code; not the grid nor the entry, so that a point a changed grid keeps,
        or another entry on the scenario asks for, is not computed again (a point's K_i,
        method, set variant and seed are its file's name in the keyed folder)."""
        return self.stage_key("k_selection_points", ksel)

    def k_selection_grid(self, ksel: str) -> str:
        """The grids of one k_selection entry
        (:class:`~ssmobs.config.stage_inputs.KSelectionGridInputs`): its points' folder (their
        key) with what every point reads, the grid of K_i, the grid files and the scenario's
        name (written into them)."""
        return self.stage_key("k_selection_grid", ksel)

    def map_cells(self, name: str) -> list[tuple[dict[str, Any], str]]:
        """Every cell of one observability map (issue 21), its scenario entry
        (:func:`ssmobs.config.maps.cell_entries`) with its own key: what the cell reads
        (:class:`~ssmobs.config.stage_inputs.MapCellInputs`: no name, no map), the model's
        code and the cells' code.  A cell two maps share, or that an extended grid keeps,
        has the same key; :meth:`lookup` of ``("map_cell", cell name, key)`` gives
        ``{"inputs": ...}``, the object the key is made of."""
        entry = next(m for m in self.config["observability_maps"] if m["name"] == name)
        out = []
        for cell in cell_entries(entry):
            inputs = map_cell_inputs(cell, self.config, design=self.design, exact=entry["exact"])
            payload = {
                "inputs": inputs_payload(inputs),
                "model_code": self.model_code(inputs.model),
                "code": self.code("map_cells"),
            }
            key = self._key("map_cell", cell["name"], payload, inputs=inputs)
            out.append((cell, key))
        return out

    def map_table(self, name: str) -> str:
        """The table of every cell of one observability map: what rule
        observability_map_cells reads (:class:`~ssmobs.config.stage_inputs.MapCellsInputs`:
        the map's name and varied parameter, each cell's key and inputs); :meth:`lookup` of
        ``("map", name, key)`` gives ``{"inputs": ...}``, the rule's only param."""
        entry = next(m for m in self.config["observability_maps"] if m["name"] == name)
        cells = [
            (key, self.lookup("map_cell", cell["name"], key)["inputs"])
            for cell, key in self.map_cells(name)
        ]
        inputs = map_cells_inputs(entry, cells)
        payload = {"inputs": inputs_payload(inputs), "code": self.code("map_cells")}
        return self._key("map", name, payload, inputs=inputs)

    def output(self, name: str, inputs: Iterable[str], params: Any) -> str:
        """A table or figure of ``outputs_dir``: its keyed inputs, its parameters and the
        code of the tables and figures."""
        files = sorted(str(p) for p in inputs)
        payload = {
            "inputs": files,
            # inputs the workflow does not make (config/paper_values.yaml) by their content;
            # the others (keyed results, stamped tables) are keyed by their paths and stamps
            "contents": {
                p: file_digest(self.repo / p)
                for p in files
                if p.startswith("config/") and (self.repo / p).is_file()
            },
            "params": params,
            "code": self.code("outputs"),
        }
        return self._key("output", name, payload)


def main(argv: list[str] | None = None) -> int:
    """Print every key of a config with what it is keyed by (JSON)."""
    import argparse

    from .config.preflight import load_config_file
    from .config.validation import validate

    parser = argparse.ArgumentParser(description=main.__doc__)
    parser.add_argument("--configfile", default="config/config.yaml")
    parser.add_argument("--backend", help="default: the config's stan.backend")
    args = parser.parse_args(argv)
    config = load_config_file(args.configfile)
    validate(config)
    backend = args.backend or config["stan"]["backend"]
    keys = CacheKeys.for_backend(config, backend)
    for name, sc in keys.scenarios.items():
        keys.trajectories(name)
        if sc.get("joint_map"):
            keys.joint_map(name)
        if sc.get("stan"):
            keys.nuts_records(name)
    for ksel in keys.k_selections:
        keys.k_selection_grid(ksel)
    print(json.dumps(keys.describe(), indent=1, sort_keys=True))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
