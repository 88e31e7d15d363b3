"""Checks before Snakemake (make targets): config file messages and stale-lock removal."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest
from repo_paths import REPO_DIR, WORKFLOW_DIR
from ssmobs.config import preflight
from ssmobs.config.validation import ConfigError, check_config_files, read_config_file

pytestmark = pytest.mark.unit


def message(path) -> str:
    with pytest.raises(ConfigError) as err:
        preflight.check_config_file(path)
    text = str(err.value)
    return text


def run_preflight(config_file: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    """``python -m ssmobs.config.preflight <config_file>`` in ``cwd``, as the make targets run
    it."""
    return subprocess.run(
        [sys.executable, "-m", "ssmobs.config.preflight", config_file],
        capture_output=True,
        text=True,
        cwd=cwd,
        env={"PYTHONPATH": str(WORKFLOW_DIR), "PATH": "/usr/bin:/bin"},
        timeout=120,
    )


def test_missing_file_is_one_line(tmp_path):
    msg = message(tmp_path / "nope.yaml")
    assert msg == f"config file {tmp_path / 'nope.yaml'} does not exist"


def test_yaml_syntax_error_gives_file_line_and_column(tmp_path):
    path = tmp_path / "bad.yaml"
    path.write_text("scenarios:\n  - {name: a, model: same\n  bad: [\n")
    msg = message(path)
    assert msg.startswith(f"config file {path}, line 3, column 6: YAML syntax error: ")
    assert "\n" not in msg


def test_tab_indentation_error_located(tmp_path):
    path = tmp_path / "tab.yaml"
    path.write_text("scenarios:\n\t- {name: a}\n")
    assert f"config file {path}, line 2, column 1: YAML syntax error" in message(path)


@pytest.mark.parametrize("text", ["", "# only a comment\n", "\n\n"])
def test_empty_file_names_file_and_required_key(tmp_path, text):
    path = tmp_path / "empty.yaml"
    path.write_text(text)
    msg = message(path)
    assert msg == (
        f"config file {path} is empty; it needs at least the key 'scenarios' "
        f"(a list of scenarios; see config/README.md)"
    )


def test_file_without_scenarios_or_not_a_mapping(tmp_path):
    path = tmp_path / "c.yaml"
    path.write_text("stan: {chains: 2}\n")
    assert "has no key 'scenarios'" in message(path)
    path.write_text("- 1\n- 2\n")
    assert "top level must be a mapping" in message(path)


def test_invalid_values_name_the_file(tmp_path):
    path = tmp_path / "c.yaml"
    path.write_text(
        "scenarios:\n  - {name: s, model: same, omega: {a: 0.9}, x0: 8, T: 4, "
        "K: 10}\nconvergence: {ess_bulk_min: .nan}\n"
    )
    msg = message(path)
    assert msg.startswith(f"config file {path}: invalid configuration")
    assert "convergence.ess_bulk_min = nan: must be a finite number" in msg


@pytest.mark.parametrize("name", ["config.yaml", "smoke.yaml", "paper.yaml"])
def test_profiles_pass(name):
    assert preflight.check_config_file(REPO_DIR / "config" / name)["scenarios"]


def test_command_line_prints_one_line_and_fails(tmp_path):
    proc = run_preflight(str(tmp_path / "x.yaml"), cwd=tmp_path)
    assert proc.returncode == 1
    assert proc.stderr == f"error: config file {tmp_path / 'x.yaml'} does not exist\n"


def not_a_config(tmp_path: Path, kind: str) -> Path:
    """A path Snakemake's own reader of --configfile fails on with a traceback."""
    if kind == "directory":
        return tmp_path
    path = tmp_path / kind
    if kind == "fifo":  # a named pipe: reading it would block until a writer comes
        os.mkfifo(path)
    elif kind == "binary":  # the start of an executable: not UTF-8
        path.write_bytes(b"\x7fELF\x02\x01\x01\x00" + bytes(range(128, 256)) * 4)
    else:  # UTF-8, but binary: NUL bytes
        path.write_bytes(b"\x00" * 64 + b"scenarios: []\n")
    return path


@pytest.mark.parametrize("kind", ["directory", "fifo", "binary", "nul_bytes"])
def test_a_file_that_is_no_config_text_is_one_line_from_the_command_line(tmp_path, kind):
    """Issue 35: `--configfile` with a binary file or a directory.  Snakemake reads
    --configfile itself before any code of the workflow runs (see the next test), so the
    preflight of the make targets must say it in one line: before, a NUL byte gave two
    lines and a named pipe (or /dev/null) 'does not exist'."""
    path = not_a_config(tmp_path, kind)
    proc = run_preflight(str(path), cwd=tmp_path)
    assert proc.returncode == 1
    assert len(proc.stderr.splitlines()) == 1, proc.stderr
    what = {
        "directory": "is a directory, not a file",
        "fifo": "is not a regular file",
        "binary": "is not a text file",
        "nul_bytes": "is not a text file",
    }[kind]
    assert proc.stderr.startswith(f"error: config file {path} {what}"), proc.stderr
    assert "a config file is YAML or JSON text" in proc.stderr


@pytest.mark.parametrize("kind", ["directory", "binary"])
def test_snakemakes_own_reader_of_configfile_fails_before_the_workflow_runs(tmp_path, kind):
    """Why the preflight checks these files (docs/getting-started.md says so): Snakemake
    reads --configfile while it parses its command line, before the Snakefile, and raises
    an error of Python, not one of its own one-line WorkflowErrors, so `snakemake
    --configfile <directory>` prints a traceback no code of ours can shorten.  If a
    Snakemake release reads them itself in one line, this fails: update the docs."""
    from snakemake.common.configfile import load_configfile
    from snakemake_interface_common.exceptions import WorkflowError

    with pytest.raises(Exception) as err:
        load_configfile(not_a_config(tmp_path, kind))
    assert not isinstance(err.value, WorkflowError)
    assert isinstance(err.value, (IsADirectoryError, UnicodeDecodeError))


# ------------------------------------------------- configs that silently mean something else
SCENARIO = "scenarios:\n  - name: s\n    model: same\n    omega: {a: 0.9}\n    x0: 8\n"


def test_duplicate_key_in_one_mapping_gives_file_line_and_key(tmp_path):
    path = tmp_path / "c.yaml"
    path.write_text(SCENARIO + "    T: 4\n    K: 12\n    K: 2\n")
    assert message(path) == (
        f"config file {path}, line 8, column 5: key 'K' appears twice in one mapping "
        f"(also line 7); YAML would silently keep only the last value: remove one"
    )


def test_second_top_level_block_refused(tmp_path):
    path = tmp_path / "c.yaml"
    path.write_text("stan:\n  chains: 2\n" + SCENARIO + "    T: 4\n    K: 2\nstan:\n  chains: 4\n")
    msg = message(path)
    assert msg.startswith(f"config file {path}, line 10, column 1: key 'stan' appears twice")
    # the Snakefile's own reading of config/config.yaml goes through load_config_file
    with pytest.raises(ConfigError, match="key 'stan' appears twice"):
        preflight.load_config_file(path)


def test_duplicate_key_in_a_flow_mapping_and_in_json_refused(tmp_path):
    path = tmp_path / "c.yaml"
    path.write_text(SCENARIO + "    T: 4\n    K: 2\nstan: {chains: 2, chains: 4}\n")
    assert "line 8, column 19: key 'chains' appears twice" in message(path)
    path = tmp_path / "c.json"
    path.write_text('{"scenarios": [], "scenarios": []}')
    assert message(path) == (
        f"config file {path}: key 'scenarios' appears twice in one JSON object; JSON "
        f"readers silently keep only the last value: remove one"
    )


def test_merge_keys_and_tab_indented_json_still_read(tmp_path):
    from ssmobs.config.validation import parse_config_text

    assert parse_config_text("b: &b {x: 1, y: 2}\nc: {<<: *b, y: 3}\n")["c"] == {"x": 1, "y": 3}
    assert parse_config_text('{\n\t"stan": {\n\t\t"chains": 2\n\t}\n}') == {"stan": {"chains": 2}}


def test_config_file_larger_than_5_mib_refused_before_parsing(tmp_path):
    path = tmp_path / "big.yaml"
    path.write_text(SCENARIO + "# padding\n" * 600_000)
    msg = message(path)
    assert msg.startswith(f"config file {path} has ") and "5 MiB" in msg
    assert "\n" not in msg


@pytest.mark.parametrize("levels", [6, 9], ids=["1e6", "1e9"])
def test_yaml_alias_bomb_refused_quickly(tmp_path, levels):
    lines = ["l0: &l0 [1, 1, 1, 1, 1, 1, 1, 1, 1, 1]"]
    lines += [f"l{i}: &l{i} [{', '.join([f'*l{i - 1}'] * 10)}]" for i in range(1, levels)]
    path = tmp_path / "bomb.yaml"
    path.write_text("\n".join(lines) + f"\n{SCENARIO}    T: 4\n    K: 2\n")
    start = time.perf_counter()
    msg = message(path)
    assert time.perf_counter() - start < 5
    assert msg == (
        f"config file {path}, line 1, column 1: holds more than 100000 values once its "
        f"YAML aliases (*name) are expanded; a config has a few hundred"
    )


def test_command_line_prints_the_duplicate_key(tmp_path):
    path = tmp_path / "c.yaml"
    path.write_text(SCENARIO + "    T: 4\n    K: 12\n    K: 2\n")
    proc = run_preflight(str(path), cwd=tmp_path)
    assert proc.returncode == 1
    assert proc.stderr.startswith(f"error: config file {path}, line 8, column 5: key 'K'")


def makefile_recipes() -> dict[str, list[str]]:
    """Each Makefile target's recipe lines (tab-indented lines under `target: ...`)."""
    recipes: dict[str, list[str]] = {}
    target = None
    for line in (REPO_DIR / "Makefile").read_text().splitlines():
        if line.startswith("\t") and target is not None:
            recipes[target].append(line.strip())
        elif m := re.match(r"^([A-Za-z0-9_-]+):(?!=)", line):
            target = m.group(1)
            recipes[target] = []
        elif line.strip() and not line.startswith("#"):
            target = None
    return recipes


def test_every_make_target_that_runs_snakemake_runs_the_preflight_first():
    """Issue 19: every target resumes a killed run with the same command, which needs the
    stale lock removed before Snakemake starts (the README promises it for every target)."""
    recipes = makefile_recipes()
    runs = {t: r for t, r in recipes.items() if any("$(SNAKEMAKE)" in x for x in r)}
    assert {"run", "smoke", "paper", "variant-table"} <= set(runs)
    for target, lines in runs.items():
        first = next(i for i, x in enumerate(lines) if "$(SNAKEMAKE)" in x)
        assert any(x.startswith("$(PREFLIGHT)") for x in lines[:first]), target
    wrapped = [t for t, r in recipes.items() if any("with_provenance" in x for x in r)]
    assert {"tables", "section4", "map", "committed"} <= set(wrapped)
    assert "$(PREFLIGHT) $(1)" in (REPO_DIR / "Makefile").read_text()  # inside with_provenance


# ------------------------------------------------------------------------ writable folders
REMEDIES = {"results": "make results/ writable", "paper_figures/mine": "set outputs_dir"}


def test_folders_that_can_be_written_give_no_problem_and_nothing_is_written(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "results").mkdir()
    files = ["results/a/b/c.json", "paper_figures/mine/t.csv", ".snakemake/locks/-"]
    assert preflight.write_problem(files, REMEDIES, "D") is None
    assert preflight.snakemake_folder_problem() is None
    assert sorted(p.name for p in tmp_path.iterdir()) == ["results"]  # asks, never writes


def test_a_file_where_a_folder_must_be_is_named_with_what_to_do(tmp_path, monkeypatch):
    """Works as any user (root too): no permission bit is involved."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "paper_figures").write_text("not a folder\n")
    problem = preflight.write_problem(
        ["results/x.json", "paper_figures/mine/t.csv", "paper_figures/mine/t.md"], REMEDIES, "D"
    )
    assert problem == (
        "this run cannot write where its jobs write: paper_figures (a file, not a folder); "
        "set outputs_dir"
    )


def in_child(code: str, cwd: Path, prefix: list[str] | None = None) -> str:
    """Run ``code`` in a child Python in ``cwd`` (after ``prefix``); its stdout."""
    proc = subprocess.run(
        [*(prefix or []), sys.executable, "-c", code],
        capture_output=True,
        text=True,
        cwd=cwd,
        env={"PYTHONPATH": str(WORKFLOW_DIR), "PATH": "/usr/bin:/bin"},
        timeout=120,
    )
    assert proc.returncode == 0, proc.stderr
    return proc.stdout.strip()


ASK = (
    "from ssmobs.config.preflight import write_problem\n"
    "print(write_problem(['results/a/x.json', 'results/b/y.json', 'results/z.json'], "
    "{'results': 'make results/ writable'}, 'D'))\n"
    "try:\n"
    "    open('results/probe', 'w')\n"
    "except OSError as err:\n"
    "    print('refused', err.errno)\n"
)


def test_a_folder_without_write_permission_is_named_once(tmp_path):
    """chmod a-w results.  Root writes through permission bits, so as root the check runs
    in a child without root's override of them (setpriv drops CAP_DAC_OVERRIDE): the
    child is then refused the write exactly as another user would be."""
    prefix = []
    if os.geteuid() == 0:
        if shutil.which("setpriv") is None:
            pytest.skip("running as root, and setpriv (to drop root's override) is missing")
        prefix = ["setpriv", "--bounding-set", "-dac_override,-dac_read_search"]
    for sub in ("results/a", "results/b"):
        (tmp_path / sub).mkdir(parents=True)
    for folder in (tmp_path / "results/a", tmp_path / "results/b", tmp_path / "results"):
        folder.chmod(0o555)
    try:
        out = in_child(ASK, tmp_path, prefix).splitlines()
    finally:
        for folder in (tmp_path / "results", tmp_path / "results/a", tmp_path / "results/b"):
            folder.chmod(0o755)
    uid = os.geteuid()
    assert out == [
        f"this run cannot write where its jobs write: results (not writable by user {uid} "
        f"(mode 555, owner {uid})); make results/ writable",
        "refused 13",  # the check agrees with what a write meets
    ]


def test_a_read_only_file_system_is_named(tmp_path):
    """A read-only bind mount of results/ in a private mount namespace (root in a container
    or VM may do it; elsewhere skipped): read-only even for root."""
    (tmp_path / "results" / "a").mkdir(parents=True)
    ro = str(tmp_path / "results")
    script = f'mount --bind {ro} {ro} && mount -o remount,bind,ro {ro} && exec "$@"'
    prefix = ["unshare", "-m", "--propagation", "private", "sh", "-c", script, "sh"]
    try:
        probe = subprocess.run([*prefix, "true"], capture_output=True, timeout=30)
    except FileNotFoundError:
        pytest.skip("unshare is not installed")
    if probe.returncode != 0:
        pytest.skip(f"a read-only bind mount cannot be made here: {probe.stderr.decode()[-200:]}")
    out = in_child(ASK, tmp_path, prefix).splitlines()
    assert out == [
        "this run cannot write where its jobs write: results (on a read-only file system); "
        "make results/ writable",
        "refused 30",  # EROFS
    ]


def test_the_make_targets_stop_when_snakemake_cannot_write_its_folder(tmp_path):
    """Snakemake keeps its lock in .snakemake/ and fails with a traceback (a dry run too)
    when it cannot write there; the preflight says it in one line (here a file is in the
    way, which holds for root too)."""
    (tmp_path / ".snakemake").write_text("not a folder\n")
    proc = run_preflight(str(REPO_DIR / "config" / "smoke.yaml"), cwd=tmp_path)
    assert proc.returncode == 1
    assert proc.stderr == (
        "error: this run cannot write where its jobs write: .snakemake (a file, not a "
        "folder); Snakemake keeps its lock and records in .snakemake/ of the working "
        "directory: make it writable, or run in a writable copy of the workflow\n"
    )


@pytest.mark.parametrize(
    ("written", "form", "yaml11"),
    [
        ("010", "a leading zero", "8"),
        ("050", "a leading zero", "40"),
        ("4:00", "base-60 (sexagesimal)", "240"),
        ("1_0", "underscores", "10"),
        ("0x8", "hexadecimal", "8"),
        ("0o7", "a number in YAML 1.2 but a string here", None),
        ("1e3", "a number in YAML 1.2 but a string here", None),
        ("0b11", "octal or binary", "3"),
        ("1_000.5", "underscores", "1000.5"),
        ("010.5", "a leading zero", "10.5"),
    ],
)
def test_numbers_in_yaml_11_forms_are_refused_with_key_and_line(tmp_path, written, form, yaml11):
    """Found read silently before (issue 46): ``K: 010`` ran K = 8, ``K: 4:00`` 240,
    ``K: 1_0`` 10, ``K: 0x8`` 8; YAML 1.2 reads them otherwise (or as strings)."""
    path = tmp_path / "c.yaml"
    path.write_text(SCENARIO + f"    T: 4\n    K: {written}\n")
    msg = message(path)
    assert msg.startswith(f"config file {path}, line 7, column 8: key 'scenarios[0].K': {written}")
    assert form in msg and "\n" not in msg
    if yaml11 is not None:
        assert f"as {yaml11}" in msg
    # Snakemake's own reading of --configfile is checked by the same reader (common.smk)
    with pytest.raises(RuntimeError, match=r"scenarios\[0\]\.K"):
        check_config_files([path], error=RuntimeError)


def test_numbers_in_yaml_12_forms_are_read_as_written(tmp_path):
    path = tmp_path / "c.yaml"
    path.write_text(
        SCENARIO + "    T: 0\n    K: -12\nstan: {adapt_delta: 0.95, init_radius: 2., x: .5}\n"
        "figure2: {K: +3, seed: 1.5e+3, q: [1, 20, 300]}\nother: {a: .inf, b: -.inf, c: .nan}\n"
    )
    data = read_config_file(path)
    assert data["scenarios"][0]["K"] == -12 and data["scenarios"][0]["T"] == 0
    assert data["stan"] == {"adapt_delta": 0.95, "init_radius": 2.0, "x": 0.5}
    assert data["figure2"] == {"K": 3, "seed": 1500.0, "q": [1, 20, 300]}


def test_a_number_form_in_a_list_names_its_place(tmp_path):
    path = tmp_path / "c.yaml"
    path.write_text(SCENARIO + "    T: 4\n    K: 2\nk_selection: [{K_grid: [10, 020]}]\n")
    assert "key 'k_selection[0].K_grid[1]': 020 is a number with a leading zero" in message(path)
    path.write_text(SCENARIO + "    T: 4\n    K: 2\nname: '010'\n")  # a quoted string stays
    assert read_config_file(path)["name"] == "010"
