"""What the workflow tidies before and after a run (ssmobs.housekeeping): stale stamps,
damaged files, leftovers of an earlier config and the guards' lines."""

from __future__ import annotations

import json
import shutil
import time
from pathlib import Path
from types import SimpleNamespace

import pytest
from ssmobs import housekeeping as hk
from ssmobs.io import checksum_problem, damaged_files, record_checksums, write_checksum

pytestmark = pytest.mark.unit


# -- stale stamps ----------------------------------------------------------------------------


@pytest.fixture
def stamps(tmp_path: Path) -> dict[str, str]:
    """Four stamps: current, stale, missing, and missing but moved aside by a dry run."""
    files = {name: str(tmp_path / f"{name}.key") for name in ("current", "stale", "new", "aside")}
    Path(files["current"]).write_text("aaaaaaaaaaaa\n")
    Path(files["stale"]).write_text("bbbbbbbbbbbb\n")
    Path(f"{files['aside']}.stale").write_text("cccccccccccc\n")
    return files


def test_a_stamp_of_another_key_is_stale_and_a_missing_one_only_when_set_aside(stamps):
    states = hk.read_stamps(stamps.values())
    key = "aaaaaaaaaaaa"
    assert [hk.stamp_is_stale(states[p], key) for p in stamps.values()] == [
        False,
        True,
        False,
        True,
    ]


def test_a_run_removes_stale_stamps_with_the_files_of_their_old_key(stamps):
    current = {path: "aaaaaaaaaaaa" for path in stamps.values()}
    outputs = {stamps["stale"]: ["out/table.csv", "out/table.md"], stamps["aside"]: ["out/f.png"]}
    changes = hk.stale_stamp_changes(
        current, {}, hk.read_stamps(stamps.values()), False, lambda p: outputs.get(p, [])
    )
    stale, aside = Path(stamps["stale"]), Path(stamps["aside"])
    assert changes == [
        (Path("out/table.csv"), None),
        (Path("out/table.md"), None),
        (stale, None),
        (Path(f"{stale}.stale"), None),
        (Path("out/f.png"), None),
        (aside, None),
        (Path(f"{aside}.stale"), None),
    ]


def test_a_dry_run_only_moves_a_stale_stamp_aside(stamps):
    current = {path: "aaaaaaaaaaaa" for path in stamps.values()}
    changes = hk.stale_stamp_changes(
        current, {}, hk.read_stamps(stamps.values()), True, lambda p: ["out/table.csv"]
    )
    stale, aside = Path(stamps["stale"]), Path(stamps["aside"])
    assert changes == [(stale, Path(f"{stale}.stale")), (aside, Path(f"{aside}.stale"))]


def test_a_rule_made_on_request_keeps_its_files_until_asked_for(stamps):
    on_request = {stamps["stale"]: "aaaaaaaaaaaa"}
    changes = hk.stale_stamp_changes(
        {}, on_request, hk.read_stamps([stamps["stale"]]), False, lambda p: ["committed.csv"]
    )
    stale = Path(stamps["stale"])
    assert changes == [(stale, None), (Path(f"{stale}.stale"), None)]


# -- damaged files ---------------------------------------------------------------------------


def test_a_damaged_trajectory_file_is_named_and_a_sound_one_is_kept(tmp_path):
    sound, damaged, unchecked = (tmp_path / n for n in ("sound.nc", "damaged.nc", "bare.nc"))
    for path in (sound, damaged, unchecked):
        path.write_bytes(b"trajectories")
    write_checksum(sound)
    write_checksum(damaged)
    damaged.write_bytes(b"trajectorieZ")  # same size, other bytes
    paths = [str(sound), str(damaged), str(unchecked), str(tmp_path / "missing.nc")]
    repairs = hk.damaged_trajectory_repairs({p: checksum_problem(p) for p in paths})
    assert repairs.changes == [(damaged, None), (unchecked, None)]
    assert repairs.warnings[0] == f"made again: {damaged} does not match its checksum " + (
        "(damaged or changed after it was written)"
    )
    assert "has no checksum" in repairs.warnings[1]
    assert repairs.targets == []


def test_a_batch_with_changed_records_reruns_with_its_gathered_files():
    gathered = ("g/summary.json", "g/marginal_map.parquet")
    batches = [
        hk.BatchState("b/batch0.parquet", None, True, True, gathered),  # sound
        hk.BatchState(
            "b/batch1.parquet", "record 7 changed; this batch reruns it", True, True, gathered
        ),
        hk.BatchState("b/batch2.parquet", None, False, True, gathered),  # deleted by hand
        hk.BatchState("b/batch3.parquet", None, False, False, gathered),  # still to run
    ]
    repairs = hk.damaged_batch_repairs(batches)
    assert repairs.warnings == [
        "this batch reruns: record 7 changed",
        "this batch reruns: b/batch2.parquet was deleted",
    ]
    removed = [str(p) for p, aside in repairs.changes if aside is None]
    assert removed == ["b/batch1.parquet", *gathered, "b/batch2.parquet", *gathered]


def test_damaged_outputs_are_removed_and_those_of_current_keys_made_again(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    files = {
        "current": Path("results/sc/joint_map/0123456789ab/summary.json"),
        "old_key": Path("results/sc/joint_map/ba9876543210/summary.json"),
        "found": Path("results/sc/design_trajectories/0123456789ab/trajectories.nc"),
        "sound": Path("results/sc/check_model/0123456789ab.json"),
        "output": Path("paper_figures/mine/table.csv"),
    }
    for path in files.values():
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text("written by its job\n")
    record_checksums(files.values())
    for name in ("current", "old_key", "found", "output"):
        files[name].write_text("changed afterwards\n")
    repairs = hk.damaged_output_repairs(damaged_files(), [files["found"]], {"0123456789ab"})
    assert sorted(p for p, _ in repairs.changes) == sorted(
        [files["current"], files["old_key"], files["output"]]
    )
    assert repairs.targets == [str(files["current"])]
    assert all(line.startswith("made again, not reused: ") for line in repairs.warnings)


def test_the_checksum_file_of_a_file_found_elsewhere_is_said_there_only():
    found = Path("results/sc/design_trajectories/0123456789ab/trajectories.nc")
    damaged = [(Path(f"{found}.sha256"), "damaged"), (Path("results/x/0123456789ab.json"), "d")]
    repairs = hk.damaged_output_repairs(damaged, [found], {"0123456789ab"})
    assert repairs.changes == [(Path("results/x/0123456789ab.json"), None)]


def test_keys_are_read_from_folders_and_stems_and_describe_names():
    path = Path("results/sc/sample_nuts/0123456789ab/batch0.parquet")
    assert hk.path_keys(path) == ["0123456789ab"]
    assert hk.path_keys(Path("results/sc/check_model/fedcba987654.json")) == ["fedcba987654"]
    assert hk.current_keys(["joint_map:sc:0123456789ab", "design::fedcba987654"]) == {
        "0123456789ab",
        "fedcba987654",
    }


# -- making the changes ----------------------------------------------------------------------


def test_changes_are_made_once_each_and_only_for_existing_files(tmp_path):
    gone, moved, kept = tmp_path / "gone.key", tmp_path / "moved.key", tmp_path / "kept.csv"
    for path in (gone, moved, kept):
        path.write_text("x")
    aside = tmp_path / "moved.key.stale"
    changes = [(gone, None), (moved, aside), (gone, None), (tmp_path / "never", None)]
    pending = hk.pending_changes(changes, Path.exists)
    assert pending == [(gone, None), (moved, aside)]
    assert hk.changed_files(pending) == [gone, moved, aside]
    hk.apply_changes(pending)
    assert not gone.exists() and not moved.exists() and aside.read_text() == "x"
    assert kept.exists()


def test_a_dry_run_that_cannot_change_stale_files_names_three_and_counts_the_rest():
    changes = [(Path(f"s{i}.key"), None) for i in range(5)]
    assert hk.left_stale_message(changes, "results is read-only") == (
        "this dry run leaves the stale s0.key, s1.key, s2.key and 2 more: results is read-only"
    )


# -- leftovers -------------------------------------------------------------------------------


def test_a_leftover_is_found_and_a_made_or_kept_file_is_not(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    names = ["old_table.csv", "table.csv", "README.md", "notes.txt", "fig.png", "provenance.json"]
    for name in names:
        (out / name).write_text("x")
    made = {str(out / "table.csv"), str(out / "fig.png")}
    assert hk.leftover_outputs(sorted(out.iterdir()), made) == [out / "old_table.csv"]


def test_stamps_of_rules_this_config_lacks_are_unknown(tmp_path):
    known, other = tmp_path / "paper_tables.key", tmp_path / "map_old.key"
    assert hk.unknown_stamps([known, other], {str(known)}) == [other]


def test_leftovers_go_to_a_folder_named_by_the_time_and_are_listed():
    now = time.strptime("2026-12-05 06:30:01", "%Y-%m-%d %H:%M:%S")
    aside = hk.set_aside_folder(Path("results/outputs/out"), now)
    assert aside == Path("results/outputs/out/set_aside/20261205T063001")
    left = [Path(f"out/t{i}.csv") for i in range(7)]
    message = hk.set_aside_message(left, "out", aside)
    assert message.startswith("moved 7 file(s) that this config does not make out of out ")
    assert message.endswith(": t0.csv, t1.csv, t2.csv, t3.csv, t4.csv, t5.csv, ...")


# -- guards ----------------------------------------------------------------------------------


def test_committed_outputs_of_another_profile_are_not_overwritten(tmp_path):
    out = str(tmp_path / "paper")
    assert hk.committed_owner(out) is None
    Path(out).mkdir()
    (Path(out) / "provenance.json").write_text('{"config_file": "config/paper.yaml"}')
    owner = hk.committed_owner(out)
    assert owner == "config/paper.yaml"
    assert hk.committed_outputs_problem(out, owner, ["config/paper.yaml"]) is None
    problem = hk.committed_outputs_problem(out, owner, ["config/smoke.yaml"])
    assert problem is not None
    assert "holds the committed outputs of config/paper.yaml" in problem
    assert "this run's config (config/smoke.yaml) must write its own outputs_dir" in problem


def test_the_files_of_jobs_include_logs_and_benchmarks():
    jobs = [
        SimpleNamespace(output=["a.nc"], log=["a.log"], benchmark="a.tsv"),
        SimpleNamespace(output=["b.json", "b.csv"], log=[], benchmark=None),
    ]
    assert hk.job_files(jobs) == ["a.nc", "a.log", "a.tsv", "b.json", "b.csv"]


def test_the_lines_name_what_to_do():
    assert "set outputs_dir (e.g. out/my_study)" in hk.outputs_dir_unset_warning([], "out")
    assert "outputs_dir is not set in the config" in hk.outputs_dir_unset_warning([], "out")
    line = hk.missing_compiler_problem(["same", "sep"], "g++")
    assert "must build 2 program(s) (same, sep)" in line and "'g++'" in line
    remedies = hk.write_remedies("out", "/cache")
    assert set(remedies) == {"results", "out", "/cache"}


def test_an_empty_program_cache_has_built_no_program(tmp_path, monkeypatch):
    monkeypatch.setenv("SSMOBS_CACHE", str(tmp_path / "empty_cache"))
    from ssmobs.stan_backends import stan_file

    programs = {m: (stan_file(m), None) for m in ("same", "sep")}
    assert hk.unbuilt_programs(programs) == ["same", "sep"]
    assert hk.unbuilt_programs({}) == []


# -- outputs without their checksum record (issue 61) -----------------------------------------


def test_an_output_without_its_checksum_record_is_unverified(tmp_path, monkeypatch):
    """Found trusted before (issue 61): a joint MAP summary edited and its record deleted
    gave a table with the edited |K^max|; results copied without results/checksums/ too."""
    monkeypatch.chdir(tmp_path)
    files = {name: Path("results") / "sc" / name for name in ("a.json", "b.json", "c.json")}
    for path in files.values():
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text("{}\n")
    record_checksums(files.values())
    assert hk.unrecorded_files(files.values()) == []  # every job's outputs are recorded
    store = Path("results/checksums")
    (store / "results/sc/a.json.sha256").unlink()  # deleted
    (store / "results/sc/b.json.sha256").write_text("garbage\n")  # cannot vouch
    missing = Path("results/sc/never_made.json")  # no file: Snakemake makes it
    found = hk.unrecorded_files([*files.values(), missing])
    assert [p for p, _ in found] == [files["a.json"], files["b.json"]]
    assert all("has no checksum record" in why for _, why in found)
    # results copied without their records: every output is unverified
    import shutil

    shutil.rmtree(store)
    assert [p for p, _ in hk.unrecorded_files(files.values())] == sorted(files.values())
    # and made again, as a damaged one: removed, and a target where its keys are current
    keyed = Path("results/sc/joint_map/0123456789ab/summary.json")
    repairs = hk.damaged_output_repairs([(keyed, "why")], [], {"0123456789ab"})
    assert repairs.changes == [(keyed, None)] and repairs.targets == [str(keyed)]


# -- program markers whose program is gone (issue 62) ------------------------------------------


def _marker(path: Path, program: Path, header: Path | None) -> Path:
    """A build job's marker at ``path`` naming ``program`` and ``header``."""
    path.parent.mkdir(parents=True, exist_ok=True)
    header_file = None if header is None else str(header)
    path.write_text(
        json.dumps({"backend": "native", "program_file": str(program), "header_file": header_file})
    )
    return path


def test_a_program_marker_whose_program_is_gone_is_removed(tmp_path, monkeypatch):
    """A cleared program cache leaves the marker in results/ naming a generated program that
    no longer exists: the marker is made again (its build job writes the program), not
    reused; one whose files exist stays, and so does a hand-written program's (no header)."""
    monkeypatch.chdir(tmp_path)
    cache = tmp_path / "cache" / "analytic" / "m-0123"
    cache.mkdir(parents=True)
    program, header = cache / "m.stan", cache / "m.hpp"
    program.write_text("// program\n")
    header.write_text("// header\n")
    own = tmp_path / "own.stan"
    own.write_text("// hand-written\n")
    stan = Path("results/shared/stan/native")
    kept = _marker(stan / "m" / "0123456789ab.json", program, header)
    hand = _marker(stan / "own" / "0123456789ab.json", own, None)
    header_gone = _marker(stan / "h" / "0123456789ab.json", program, cache / "gone.hpp")
    check = Path("results/sc/check_model_stan/0123456789ab.json")
    check.parent.mkdir(parents=True)
    check.write_text('{"ok": true}\n')
    record_checksums([kept, hand, header_gone, check])
    paths = [kept, hand, header_gone, check]
    assert hk.orphaned_program_markers(paths) == [
        (
            header_gone,
            f"{header_gone} names files of its Stan program that are gone "
            f"({cache / 'gone.hpp'}; was the program cache cleared?): its build job writes "
            f"them again",
        )
    ]
    shutil.rmtree(tmp_path / "cache")  # the program cache cleared
    found = hk.unrecorded_files(paths)
    assert [p for p, _ in found] == [header_gone, kept]
    (why,) = [w for p, w in found if p == kept]
    assert f"names files of its Stan program that are gone ({program}, {header}; " in why
    # removed and made again in this run (its key is current): build_stan_model runs
    repairs = hk.damaged_output_repairs(found, [], {"0123456789ab"})
    assert repairs.changes == [(header_gone, None), (kept, None)]
    assert repairs.targets == [str(header_gone), str(kept)]
    assert all(line.startswith("made again, not reused: ") for line in repairs.warnings)
    hk.apply_changes(repairs.changes)
    assert hand.is_file() and check.is_file() and not kept.exists()
    # a marker with its checksum record deleted is said once, as unrecorded
    (Path("results/checksums") / f"{hand}.sha256").unlink()
    own.unlink()
    ((path, why),) = hk.unrecorded_files(paths)
    assert path == hand and "has no checksum record" in why
