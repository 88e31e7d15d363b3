"""A smoke run of one's own study: its config on the smoke profile's small sizes.

``make smoke CONFIG=config/my_study.yaml`` runs ``python -m ssmobs.config.smoke
config/my_study.yaml --out results/smoke_configs/my_study.yaml`` and then Snakemake with that
overlay.  The overlay keeps everything that says *what* is studied (models, true values,
priors, horizons T, studies, maps, multi-start and every other setting) and takes the
sizes of ``config/smoke.yaml`` for *how much*:

- K: at most :data:`SMOKE_K` design trajectories per scenario and per map cell
  (``exact_K`` and ``stan_every`` no larger), ``stan.keep_draws`` only below it;
- NUTS: the smoke profile's ``chains``, ``iter_warmup``, ``iter_sampling`` and
  ``batch_size`` (also over a scenario's own ``stan_settings``);
- the ESS minima lowered with the chains, to 100 x chains (the rule of
  ``config/README.md``: with 2 chains, 200 instead of 400), so that a run can pass;
- a choice of K (``k_selection``): the smoke profile's grid and its first two seeds;
- ``outputs_dir``: ``paper_figures/smoke_<name>``, its own folder, so no committed output
  and not the study's own outputs_dir is written.

Every stage runs (the model check, design, joint MAP, NUTS, the exact stage, the tables and
figures): minutes instead of hours, to find a mistake before the real run.  The numbers
say nothing about the study; ``make run CONFIG=...`` computes them.
"""

from __future__ import annotations

import argparse
import copy
import sys
from pathlib import Path
from typing import Any

import yaml

from .numbers import text_number_problems
from .schema import load_schema
from .validation import ConfigError, validate

#: design trajectories per scenario and per map cell in a smoke run (the smoke profile's
#: own model scenario has K = 4)
SMOKE_K = 4
#: the NUTS sizes taken from the smoke profile's stan block
STAN_SIZES = ("chains", "iter_warmup", "iter_sampling", "batch_size")
#: the smoke profile
SMOKE_PROFILE = Path(__file__).resolve().parents[3] / "config" / "smoke.yaml"


def _at_most(value: Any, cap: Any) -> Any:
    """min(value, cap) for two integers; any other value as it is (the config check then
    names it: a float K is refused there, not cut to an integer here)."""
    whole = all(isinstance(v, int) and not isinstance(v, bool) for v in (value, cap))
    return min(value, cap) if whole else value


def smoke_overlay(
    config: dict[str, Any], name: str, smoke: dict[str, Any] | None = None
) -> dict[str, Any]:
    """``config`` (as read from its file, not validated) on the smoke profile's sizes
    (module docstring); ``name`` names its outputs_dir, ``smoke`` is the smoke profile
    (default: ``config/smoke.yaml``)."""
    if smoke is None:
        smoke = yaml.safe_load(SMOKE_PROFILE.read_text())
    sizes = {key: smoke["stan"][key] for key in STAN_SIZES}
    k_grid = smoke["k_selection"][0]["K_grid"]
    out = copy.deepcopy(config)
    out["outputs_dir"] = f"paper_figures/smoke_{name}"
    for sc in out.get("scenarios", []):
        if "K" in sc:
            sc["K"] = _at_most(sc["K"], SMOKE_K)
        if sc.get("exact_K") is not None:
            sc["exact_K"] = _at_most(sc["exact_K"], SMOKE_K)
        if "stan_every" in sc:
            sc["stan_every"] = _at_most(sc["stan_every"], sc.get("K"))
        own = sc.get("stan_settings") or {}
        for key in ("chains", "iter_warmup", "iter_sampling"):
            if key in own:
                own[key] = sizes[key]
    for entry in out.get("observability_maps", []):
        entry["K"] = _at_most(entry.get("K", SMOKE_K), SMOKE_K)
    for entry in out.get("k_selection", []):
        entry["K_grid"] = list(k_grid)
        if "seeds" in entry:
            entry["seeds"] = entry["seeds"][:2]
    stan = out["stan"] = {**(out.get("stan") or {}), **sizes}
    if "keep_draws" in stan:
        stan["keep_draws"] = [k for k in stan["keep_draws"] if k < SMOKE_K]
    ess = 100 * int(sizes["chains"])
    conv = out["convergence"] = dict(out.get("convergence") or {})
    for key in ("ess_bulk_min", "ess_tail_min"):
        conv[key] = _at_most(conv.get(key, ess), ess)
    return out


def header(source: str, overlay: dict[str, Any]) -> str:
    """The comment at the top of an overlay file: where it comes from and what it changed."""
    stan = overlay["stan"]
    return (
        f"# Made by `make smoke CONFIG={source}` (python -m ssmobs.config.smoke) from {source}:\n"
        f"# that study on the smoke profile's sizes (K <= {SMOKE_K}, {stan['chains']} chains x "
        f"({stan['iter_warmup']} + {stan['iter_sampling']}) iterations,\n"
        f"# ESS minima {overlay['convergence']['ess_bulk_min']}); its tables and figures go to "
        f"{overlay['outputs_dir']}/.\n"
        f"# Remade by every `make smoke CONFIG={source}`: edit {source}, not this file.\n"
    )


def write_overlay(source: str | Path, out: str | Path) -> dict[str, Any]:
    """Read ``source`` strictly, write its overlay to ``out`` after validating it; returns
    the overlay.  ConfigError names ``source`` when it or its overlay is invalid."""
    from .preflight import load_config_file

    config = load_config_file(source)
    # quoted numbers read as the config check reads them, so that the sizes are cut
    problems = text_number_problems(config, load_schema())
    if problems:
        raise ConfigError(f"config file {source}: " + "; ".join(problems))
    overlay = smoke_overlay(config, Path(source).stem)
    try:
        validate(copy.deepcopy(overlay))
    except ConfigError as err:
        raise ConfigError(f"config file {source} (at the smoke profile's sizes): {err}") from None
    path = Path(out)
    path.parent.mkdir(parents=True, exist_ok=True)
    text = yaml.safe_dump(overlay, sort_keys=False, allow_unicode=True)
    path.write_text(header(str(source), overlay) + text)
    return overlay


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m ssmobs.config.smoke",
        description="Write a study config's smoke overlay (the smoke profile's sizes).",
    )
    parser.add_argument("configfile", help="the study's config file")
    parser.add_argument("--out", required=True, help="where to write the overlay")
    args = parser.parse_args(argv)
    try:
        overlay = write_overlay(args.configfile, args.out)
    except ConfigError as err:
        print(f"error: {err}", file=sys.stderr)
        return 1
    print(
        f"smoke config {args.out}: {args.configfile} on the smoke profile's sizes; "
        f"its tables and figures go to {overlay['outputs_dir']}/"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
