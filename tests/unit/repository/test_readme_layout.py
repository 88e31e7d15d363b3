"""The README's rule diagram and the layout page of the docs name what the tree holds."""

from __future__ import annotations

import re

from repo_paths import PACKAGE_DIR, REPO_DIR

README = (REPO_DIR / "README.md").read_text()
#: the repository layout, a page of the documentation site
LAYOUT_PAGE = (REPO_DIR / "docs" / "reference" / "layout.md").read_text()


def _section(start: str, end: str, text: str = README) -> str:
    i = text.index(start)
    return text[i : text.index(end, i + len(start))]


def test_diagram_names_every_rule():
    diagram = _section("```mermaid", "```\n")
    rules = set()
    for smk in (REPO_DIR / "workflow" / "rules").glob("*.smk"):
        rules |= set(re.findall(r"^rule (\w+):", smk.read_text(), flags=re.M))
    rules |= set(re.findall(r"^rule (\w+):", (REPO_DIR / "Snakefile").read_text(), flags=re.M))
    rules.discard("all")
    drawn = set(re.findall(r"\[(\w+)", diagram))
    assert rules - drawn == set(), "rules missing from the README's diagram"
    assert drawn - rules == set(), "the README's diagram draws rules that do not exist"


def test_layout_names_every_module_and_rule_file():
    layout = _section("```\n", "```\n", LAYOUT_PAGE)
    package = PACKAGE_DIR
    subpackages = {p.parent.name for p in package.glob("*/__init__.py")}
    for pkg in subpackages:
        assert f"{pkg}/" in layout, f"subpackage {pkg}/ missing from docs/reference/layout.md"
    # every module but the models (one module per model) by its file name
    modules = {
        p.stem for p in package.rglob("*.py") if p.stem != "__init__" and p.parent.name != "models"
    }
    missing = {m for m in modules if not re.search(rf"\b{m}\.py\b", layout)}
    assert missing == set(), "modules missing from docs/reference/layout.md"
    named = set(re.findall(r"\b(\w+)\.py\b", layout)) - {"rule", "__init__", "test_import_graph"}
    own = {"base", "log_posterior", "symmetries", "propriety", "check_cases", "self_check"}
    known = modules | own  # the models package's own modules (models.INTERNAL_MODULES)
    assert named <= known, "layout names modules that do not exist"
    for smk in (REPO_DIR / "workflow" / "rules").glob("*.smk"):
        stem = smk.stem.replace("common", "common.smk")
        assert stem in layout, f"rule file {smk.name} missing from docs/reference/layout.md"
