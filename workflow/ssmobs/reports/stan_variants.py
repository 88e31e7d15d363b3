"""The variant x row table of Section IV (issue 20): |K^Stan|/K under Stan set-ups the paper
leaves open, beside each row's own set-up and the paper's value.

Read from committed reproductions (a folder with ``provenance.json`` and
``section4_summary.csv``): each row names its baseline, a (folder, scenario) pair; every
scenario of the study folders with the same ``paper_ref`` is a variant of it. A variant must
run on the same design trajectories as its baseline (same model, truth, T, K, prior, design
seed and method, the same every-m-th subset) and under the same convergence checks; what
differs is its Stan set-up, and that difference is its label (derived, never typed).

A row whose posterior is improper under its prior (:mod:`ssmobs.reports.propriety_notes`:
x0 drops out strictly inside the prior box) shows no |K^Stan| under any set-up: its cells
say "not shown: improper", the table's line ``improper`` gives the reason, and a
documented end-of-support finding (``edge``) keeps its numbers and is named in a line
``edge``.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import pandas as pd

from ssmobs import io
from ssmobs.binomial import format_fraction
from ssmobs.config.blocks import stan_settings
from ssmobs.config.stage_inputs import SAMPLER_FIELDS
from ssmobs.config.validation import ConfigError, read_config_file, validate
from ssmobs.reports.propriety_notes import (
    NOT_SHOWN_IMPROPER,
    PosteriorNote,
    ProprietyAnalysis,
    add_note_columns,
    config_note,
)
from ssmobs.reports.tables import write_table
from ssmobs.stage_code import code_digest, digest, file_digest, model_code

# what decides a scenario's design trajectories and its Stan subset (Sec. III)
TRAJECTORY_KEYS = ("model", "omega", "x0", "T", "method", "seed", "K", "prior", "stan_every")
# the Stan set-up: the config's stan block (scenario's stan_settings override), the gradient
# path (issue 49), inits, seed
SETUP_KEYS = (*SAMPLER_FIELDS, "gradients", "stan_init", "stan_seed")
OURS = "ours (the row's own set-up)"
#: the label of a study's run under exactly the row's own set-up (another run of it)
AGAIN = "the row's own set-up, again ({folder})"
#: the table's line naming the gradient path of each row's own set-up
GRADIENTS_LINE = "gradients of the row's own set-up"
CAPTION = (
    "Section IV under Stan set-ups the paper leaves open: |K^Stan|/K with its exact binomial "
    "95 % interval and the number of runs, per set-up (what it changes against the row's own "
    "set-up) and row, each row on the same design trajectories; the paper's |K^Stan|/K last"
)
#: what the caption adds when some row's posterior is improper
CAPTION_IMPROPER = (
    '. A row whose posterior is improper under its prior shows "not shown: improper" under '
    "every set-up and the reason in the line improper"
)
#: the columns of a line that state a Stan result (left empty for an improper posterior)
STAN_RESULTS = ("K_stan", "K_stan_frac", "K_stan_frac_lo95", "K_stan_frac_hi95")


class VariantTableError(ValueError):
    """A variant that cannot be set beside its baseline (other trajectories or checks)."""


def _study(folder: str | os.PathLike) -> tuple[dict[str, Any], pd.DataFrame]:
    """A committed reproduction's config (schema defaults filled in) and Section IV summary."""
    path = Path(folder)
    config = validate(io.read_json(path / "provenance.json", required=["config"])["config"])
    summary = pd.read_csv(path / "section4_summary.csv")
    return config, summary.set_index("scenario")


def stan_setup(config: Mapping[str, Any], scenario: Mapping[str, Any]) -> dict[str, Any]:
    """The Stan set-up one scenario's runs used (SETUP_KEYS)."""
    stan = stan_settings(scenario, config["stan"])  # the one merge (config.blocks)
    setup = {key: stan[key] for key in SETUP_KEYS if key in stan}
    setup["stan_init"] = scenario.get("stan_init", "random")
    setup["stan_seed"] = scenario.get("stan_seed")
    return setup


def _describe(key: str, value: Any) -> str:
    if key == "init_radius":
        return "every chain at 0" if value == 0 else f"inits uniform(-{value}, {value})"
    if key == "stan_init":
        return {
            "true": "inits at the true values",
            "joint_map": "inits at the joint MAP",
            "random": "random inits",
        }.get(value, f"inits {value}")
    if key == "stan_seed":
        return "a seed per run" if value is None else f"one Stan seed ({value}) for all"
    if key == "iter_warmup":
        return f"warmup {value}"
    if key == "gradients":
        return {"analytic": "analytic gradients", "autodiff": "Stan's autodiff gradients"}[value]
    return f"{key} {value}"


def setup_label(
    variant: Mapping[str, Any], baseline: Mapping[str, Any], again_in: str | None = None
) -> str:
    """What a variant's Stan set-up changes against its baseline's, in words; a study's run
    under the baseline's very set-up (``again_in``: the study's folder) is labelled as a
    repeat of it (:data:`AGAIN`), so it never takes the baseline's own cell."""
    changed = [_describe(k, variant[k]) for k in SETUP_KEYS if variant.get(k) != baseline.get(k)]
    if changed:
        return ", ".join(changed)
    return OURS if again_in is None else AGAIN.format(folder=Path(again_in).name)


def _checked_same_runs(
    where: str, config: Mapping, scenario: Mapping, base_config: Mapping, base: Mapping
) -> None:
    """Raise unless the variant runs on the baseline's trajectories under its checks."""
    differs = [k for k in TRAJECTORY_KEYS if scenario.get(k) != base.get(k)]
    differs += [k for k in ("design", "convergence") if config[k] != base_config[k]]
    if differs:
        raise VariantTableError(
            f"{where}: differs from its baseline {base['name']!r} in {differs}; a variant "
            "must run on the same design trajectories under the same convergence checks"
        )


def variant_rows(
    baselines: Sequence[Mapping[str, str]],
    studies: Sequence[str | os.PathLike],
    *,
    propriety: ProprietyAnalysis | None = None,
) -> pd.DataFrame:
    """One line per (row, set-up): |K^Stan| of the runs, its fraction with a 95 % interval,
    the paper's fraction; the baselines first, then the studies' variants in file order.
    A scenario whose posterior is improper (``propriety``: the analysis, the project's when
    None) has its Stan results (:data:`STAN_RESULTS`) empty and the reason in ``improper``;
    ``runs`` and the paper's fraction stay."""
    loaded = {os.fspath(f): _study(f) for f in [b["folder"] for b in baselines] + list(studies)}
    lines: list[dict[str, Any]] = []
    notes: list[PosteriorNote] = []
    for base_ref in baselines:
        base_config, _ = loaded[os.fspath(base_ref["folder"])]
        base = next(s for s in base_config["scenarios"] if s["name"] == base_ref["scenario"])
        base_setup = stan_setup(base_config, base)
        members = [(os.fspath(base_ref["folder"]), base)]
        for folder in [os.fspath(s) for s in studies]:
            config, _ = loaded[folder]
            for sc in config["scenarios"]:
                if sc.get("paper_ref") != base.get("paper_ref") or (folder, sc) in members:
                    continue
                _checked_same_runs(f"{folder}: {sc['name']}", config, sc, base_config, base)
                members.append((folder, sc))
        for i, (folder, sc) in enumerate(members):
            config, summary = loaded[folder]
            got = summary.loc[sc["name"]]
            note = config_note(sc, propriety)
            setup = stan_setup(config, sc)
            lines.append(
                {
                    "row": base["paper_ref"],
                    "setup": setup_label(setup, base_setup, None if i == 0 else folder),
                    "gradients": setup["gradients"],
                    "folder": folder,
                    "scenario": sc["name"],
                    # empty where the folder's own summary withheld it (improper)
                    "K_stan": None if pd.isna(got["K_stan"]) else int(got["K_stan"]),
                    "runs": int(got["K_stan_runs"]),
                    "K_stan_frac": got["K_stan_frac"],
                    "K_stan_frac_lo95": got["K_stan_frac_lo95"],
                    "K_stan_frac_hi95": got["K_stan_frac_hi95"],
                    "K_stan_frac_paper": got["K_stan_frac_paper"],
                }
            )
            if note.is_improper:
                lines[-1].update(dict.fromkeys(STAN_RESULTS, None))
            notes.append(note)
    add_note_columns(lines, notes)
    frame = pd.DataFrame(lines)
    twice = frame[frame.duplicated(["row", "setup"], keep=False)] if lines else frame
    if not twice.empty:
        first = twice.iloc[0]
        raise VariantTableError(
            f"row {first['row']!r}: set-up {first['setup']!r} twice, in "
            f"{sorted(twice[twice['row'] == first['row']]['folder'])}: one cell per set-up"
        )
    if not frame.empty:
        frame["K_stan"] = frame["K_stan"].astype("Int64")
    return frame


def _cell(line: Mapping[str, Any]) -> str:
    """A (set-up, row) cell: the fraction with its interval and the runs, or the words."""
    if line.get("improper"):
        return f"{NOT_SHOWN_IMPROPER} ({line['runs']} runs)"
    return f"{format_fraction(line['K_stan'], line['runs'])} of {line['runs']}"


def variant_by_row(lines: pd.DataFrame) -> pd.DataFrame:
    """The table to read: a line per set-up, a column per row, cells "0.76 [0.69, 0.82]" (and
    the number of runs), the paper's fractions and each row's own gradient path
    (:data:`GRADIENTS_LINE`) after them; where some row has a finding of the propriety
    analysis, the lines ``improper`` (the reason its cells are not shown) and ``edge`` (an
    end-of-support finding, numbers kept) last."""
    rows = list(dict.fromkeys(lines["row"]))
    setups = list(dict.fromkeys([OURS, *lines["setup"]]))
    cells = {(line["setup"], line["row"]): _cell(line) for line in lines.to_dict("records")}
    table = [{"Stan set-up": s, **{r: cells.get((s, r), "") for r in rows}} for s in setups]
    paper = lines.groupby("row", sort=False)["K_stan_frac_paper"].first()
    table.append({"Stan set-up": "paper", **{r: f"{paper[r]:.3f}" for r in rows}})
    own = lines[lines["setup"] == OURS].groupby("row", sort=False)["gradients"].first()
    table.append({"Stan set-up": GRADIENTS_LINE, **{r: own[r] for r in rows}})
    for column in ("improper", "edge"):
        if column in lines.columns:
            # every scenario of a row shares its model and prior, so its first line speaks
            notes = lines.groupby("row", sort=False)[column].first()
            table.append({"Stan set-up": column, **{r: notes[r] for r in rows}})
    return pd.DataFrame(table)


def caption(lines: pd.DataFrame) -> str:
    """The table's caption: :data:`CAPTION`, and what an improper row shows if there is one."""
    improper = "improper" in lines.columns and lines["improper"].astype(bool).any()
    return CAPTION + (CAPTION_IMPROPER if improper else "")


def read_spec(path: str | os.PathLike) -> dict[str, Any]:
    """The table's spec (config/tables/stan_variants_by_row.yaml): output, baselines, studies."""
    spec = read_config_file(path)
    if not isinstance(spec, dict) or set(spec) != {"output", "baselines", "studies"}:
        raise ConfigError(f"{path}: needs exactly the keys 'output', 'baselines' and 'studies'")
    for base in spec["baselines"]:
        if not isinstance(base, dict) or set(base) != {"folder", "scenario"}:
            raise ConfigError(
                f"{path}: baselines: each needs 'folder' and 'scenario', got {base!r}"
            )
    return spec


def write_variant_table(
    spec: Mapping[str, Any], csv: str | os.PathLike, md: str | os.PathLike
) -> None:
    """The spec's table: the lines to ``csv``, the table to read (with its caption) to ``md``."""
    lines = variant_rows(spec["baselines"], spec["studies"])
    write_table(lines, [csv])
    write_table(variant_by_row(lines), [md], caption=caption(lines))


def table_key(inputs: Sequence[str | os.PathLike]) -> str:
    """The rule's content key: the bytes of every file it reads, the code that reads them
    and the code of every model its rows name (:func:`row_models`; the propriety notes read
    the model's terms), so the rule reruns when any of them changes, whatever the file times
    (its stamp's content: a stamp of another key is removed before the DAG is built)."""
    files = {os.fspath(p): file_digest(os.fspath(p)) for p in inputs}
    models = {m: model_code(m) for m in row_models(inputs)}
    return digest({"inputs": files, "code": code_digest("variant_table"), "models": models})


def row_models(inputs: Sequence[str | os.PathLike]) -> list[str]:
    """The models named by the scenarios of every committed config among ``inputs`` (each
    folder's ``provenance.json``), sorted: every row's and every variant's model."""
    models = set()
    for path in inputs:
        if Path(path).name == "provenance.json":
            config = io.read_json(path, required=["config"])["config"]
            models |= {str(sc["model"]) for sc in config["scenarios"]}
    return sorted(models)


def spec_inputs(spec: Mapping[str, Any]) -> list[str]:
    """The committed files the table reads (Snakemake's inputs)."""
    folders = dict.fromkeys([b["folder"] for b in spec["baselines"]] + list(spec["studies"]))
    return [f"{f}/{name}" for f in folders for name in ("provenance.json", "section4_summary.csv")]
