"""The config profiles of ``config/``: what each runs and how, described once.

:data:`PROFILES` is the one description; :func:`table` renders it, and ``README.md`` and
``config/README.md`` show that table between the markers :data:`START` and :data:`END`
(the documentation site takes README's block by include-markdown).  ``python -m
ssmobs.config.profiles`` rewrites both blocks, ``--check`` only compares (``make docs`` runs
it).  Every YAML file of ``config/`` outside ``config/profiles/`` (Snakemake's own profiles)
must match exactly one entry, so a new profile cannot go undescribed.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from fnmatch import fnmatchcase
from pathlib import Path

#: the repository (or workflow copy) this package belongs to
REPO_DIR = Path(__file__).resolve().parents[3]
#: the pages that show the table, relative to the repository
PAGES = ("README.md", "config/README.md")
START = "<!-- profiles:start -->"
END = "<!-- profiles:end -->"
COMMAND = "python -m ssmobs.config.profiles"


@dataclass(frozen=True)
class Profile:
    """One row: the file (or a glob of files) under ``config/``, what it runs, how to run it."""

    pattern: str
    what: str
    run: str


PROFILES: tuple[Profile, ...] = (
    Profile(
        "config.yaml",
        "the default: every scenario of Section IV at reduced K and Stan iterations, sized "
        "for a first run on 2 cores",
        "`make run`, `snakemake --cores 2`",
    ),
    Profile("smoke.yaml", "every rule on tiny sizes", "CI (`tests/workflow`), `make smoke`"),
    Profile(
        "tables.yaml",
        "Tables II, III and Figure 3 at the paper's settings: Same (0.9, 8), T = 20 with "
        "K = 1300 and T = 50 with K = 3100, 4 chains × (4000 + 6000)",
        "`make tables`",
    ),
    Profile(
        "section4_sep_d2_p1.yaml",
        "one Section IV row at the paper's settings: (Sep, d=2, p=1), only a restricted, "
        "T = 50, K = 4000, 4 chains × (4000 + 6000)",
        "`make section4`",
    ),
    Profile(
        "section4_rows/*.yaml",
        "the other Section IV rows at the paper's iterations on a subset of its design set "
        "(every m-th of the paper's K)",
        "`make section4-rows`, or `make section4 SECTION4_CONFIG=<file>`",
    ),
    Profile(
        "stan_variants/*.yaml",
        "Stan set-ups the paper leaves open, varied one at a time on committed rows",
        "`make section4 SECTION4_CONFIG=<file>`",
    ),
    Profile(
        "map.yaml",
        "observability maps (ours): one parameter × T per model, K = 200 per cell (40 for "
        "the model with four parameters)",
        "`make map`",
    ),
    Profile(
        "stoch_vol.yaml",
        "our own model (stochastic volatility) over T = 20, 50, 100 (the tutorial's study)",
        "`make committed CONFIG=config/stoch_vol.yaml`",
    ),
    Profile(
        "paper.yaml",
        "the paper's T, K and Stan settings (4 chains × (4000 + 6000)) for every scenario",
        "`make paper`, a cluster",
    ),
    Profile(
        "tables/stan_variants_by_row.yaml",
        "not a profile: which committed studies the variant × row table reads",
        "`make variant-table`",
    ),
    Profile(
        "paper_values.yaml",
        "not a profile: every number the paper states for its scenarios",
        "the comparisons with the paper",
    ),
)


def config_files(repo: Path = REPO_DIR) -> list[str]:
    """The YAML files of ``config/`` a row must describe (paths relative to ``config/``)."""
    root = repo / "config"
    return sorted(
        p.relative_to(root).as_posix()
        for p in root.rglob("*.yaml")
        if p.relative_to(root).parts[0] != "profiles"
    )


def undescribed(repo: Path = REPO_DIR) -> list[str]:
    """Problems: a config file no row or several rows match, a row that matches no file."""
    files = config_files(repo)
    problems = []
    for name in files:
        rows = [p.pattern for p in PROFILES if fnmatchcase(name, p.pattern)]
        if len(rows) != 1:
            problems.append(f"config/{name}: matched by {len(rows)} rows ({rows})")
    for profile in PROFILES:
        if not any(fnmatchcase(name, profile.pattern) for name in files):
            problems.append(f"row {profile.pattern!r}: no such file in config/")
    return problems


def table() -> str:
    """The Markdown table of :data:`PROFILES` (paths from the repository's top)."""
    lines = ["| profile | what it runs | how |", "|---|---|---|"]
    lines += [f"| `config/{p.pattern}` | {p.what} | {p.run} |" for p in PROFILES]
    return "\n".join(lines) + "\n"


def with_table(page: str, name: str) -> str:
    """``page`` with the block between :data:`START` and :data:`END` replaced by the table."""
    head, start, rest = page.partition(START + "\n")
    _, end, tail = rest.partition(END)
    if not start or not end:
        raise ValueError(f"{name}: no '{START}' ... '{END}' block for the profiles table")
    return head + start + table() + end + tail


def main(argv: Sequence[str] | None = None) -> int:
    """Write (or with ``--check``, compare) the profiles table of README.md and
    config/README.md."""
    parser = argparse.ArgumentParser(description=main.__doc__)
    parser.add_argument(
        "--check", action="store_true", help="write nothing; exit 1 if a table is not current"
    )
    args = parser.parse_args(argv)
    problems = undescribed()
    for name in PAGES:
        path = REPO_DIR / name
        current = path.read_text()
        page = with_table(current, name)
        if args.check and page != current:
            problems.append(f"{name}: the profiles table is not the generated one: run {COMMAND}")
        elif page != current:
            path.write_text(page)
    for problem in problems:
        print(problem, file=sys.stderr)
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
