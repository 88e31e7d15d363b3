"""The per-trajectory NUTS loop with a fake backend: records, resume, failures, draws."""

from __future__ import annotations

import dataclasses
import json
import logging
import os

import numpy as np
import pytest
from factories import same_a09
from ssmobs import seeds
from ssmobs.log import Progress
from ssmobs.models import get_model
from ssmobs.nuts.batch import NutsBatch, run_trajectories
from ssmobs.nuts.convergence import ConvergenceSettings, apply_thresholds
from ssmobs.nuts.record_cache import RECORD_KEYS, load_records, record_path
from ssmobs.nuts.record_format import records_to_frame
from ssmobs.nuts.stan_metrics import stan_summary
from ssmobs.stan_backends.base import Draws, SamplerSettings, SamplingError

pytestmark = pytest.mark.unit

T = 5
K = 6
SAMPLER = SamplerSettings(chains=4, iter_warmup=100, iter_sampling=400)


class FakeBackend:
    """Implements the StanBackend protocol with synthetic draws.

    The behaviour for trajectory k is chosen by ``modes[k]``; the fake reads k from the
    data (the scenario's design observations below have z[k][0] = k).
    """

    name = "fake"

    def __init__(self, modes=None):
        self.modes = modes or {}
        self.compiled = []
        self.calls = []

    def compile(self, stan_file):
        self.compiled.append(stan_file)
        return {"backend": self.name, "stan_file": str(stan_file)}

    def sample(self, stan_file, data, seed, settings, inits=None):
        k = int(round(data["z"][0]))
        self.calls.append({"k": k, "seed": seed, "inits": inits, "data": data})
        mode = self.modes.get(k, "good")
        if mode == "raise":
            raise SamplingError("Initialization failed after 100 attempts")
        if mode == "bug":
            raise ZeroDivisionError("numerical exception in the fake")
        if mode == "reject":
            raise ValueError("same.stan: data rejected: empty support for a")
        rng = np.random.default_rng(seed)
        c, n, t = settings.chains, settings.iter_sampling, data["T"]
        a = 0.9 + 0.02 * rng.standard_normal((c, n))
        x0 = 8.0 + 0.5 * rng.standard_normal((c, n))
        x = np.asarray(data["z"])[None, None, :] + 0.3 * rng.standard_normal((c, n, t))
        if mode == "bad":  # chains stuck in different places
            x0 = x0 + 3.0 * np.arange(c)[:, None]
        if mode == "const":
            x0 = np.full((c, n), 8.0)
        if mode == "nan":
            x[1, 5, 0] = np.nan
        stats = {
            "divergent__": np.zeros((c, n)),
            "treedepth__": np.full((c, n), 3.0),
            "energy__": rng.standard_normal((c, n)),
            "lp__": np.zeros((c, n)),
            "accept_stat__": np.full((c, n), 0.9),
            "stepsize__": np.full((c, n), 0.5),
            "n_leapfrog__": np.full((c, n), 7.0),
        }
        return Draws(
            params={"a": a, "x0": x0, "x": x},
            sample_stats=stats,
            timings={"sample": 0.01, "transfer": 0.002},
        )


@pytest.fixture()
def scenario(tmp_path):
    model = get_model("same")
    rng = np.random.default_rng(0)
    z = rng.normal(0, 1, (K, T, 1))
    z[:, 0, 0] = np.arange(K)  # lets the fake know k
    x_true = z + 0.1
    stan_file = tmp_path / "same.stan"
    stan_file.write_text("// fake program\n")
    return {
        "model": model,
        "stan_file": stan_file,
        "z": z,
        "x_true": x_true,
        "bounds": model.prior_bounds({"a": 0.9}),
        "omega_true": np.array([0.9]),
        "x0_true": 8.0,
        "scenario": "same_T5",
        "seed": 11,
        "sampler": SAMPLER,
        "convergence": ConvergenceSettings(),
        "records_dir": tmp_path / "records",
        "draws_dir": tmp_path / "draws",
    }


#: the fields of the fixture that are NutsBatch's, and the run's own arguments
BATCH_FIELDS = {f.name for f in dataclasses.fields(NutsBatch)}


def run(sc, backend, ks=range(K), **kw):
    args = {**sc, **kw}
    batch = NutsBatch(**{k: v for k, v in args.items() if k in BATCH_FIELDS})
    return run_trajectories(
        batch,
        backend,
        list(ks),
        args["records_dir"],
        args.get("keep_draws_for", set()),
        args["draws_dir"],
        args.get("progress"),
        args.get("retry_errors", False),
    )


MODES = {1: "raise", 2: "bad", 3: "const", 4: "nan", 5: "reject"}


def test_records_for_good_and_failing_trajectories(scenario):
    backend = FakeBackend(MODES)
    recs = run(scenario, backend)
    assert [r["k"] for r in recs] == list(range(K))
    assert len(backend.compiled) == 1
    assert [c["seed"] for c in backend.calls] == [
        seeds.int_seed(11, "nuts", "same_T5", k) for k in range(K)
    ]
    for k in range(K):
        on_disk = json.loads(record_path(scenario["records_dir"], k).read_text())
        assert set(RECORD_KEYS) <= set(on_disk)
        assert on_disk["converged"] == recs[k]["converged"]

    good = recs[0]
    assert good["converged"] and good["status"] == "ok" and good["reason"] is None
    assert good["failed_checks"] == [] and good["diagnostics"]["max_rhat"] < 1.01
    assert good["theta_names"] == ["a", "x0", "x1", "x2", "x3", "x4", "x5"]
    assert good["map"][0] == pytest.approx(0.9, abs=0.01)
    assert good["map"][1] == pytest.approx(8.0, abs=0.2)
    assert all(lo < m < hi for lo, m, hi in zip(good["q5"], good["map"], good["q95"]))
    assert good["key"]["stan_seed"] == seeds.int_seed(11, "nuts", "same_T5", 0)
    t = good["timings"]
    assert t["backend"] == {"sample": 0.01, "transfer": 0.002}
    assert t["overhead"] >= t["diagnostics"] + t["marginal"] >= 0 and t["sample_call"] >= 0

    raised = recs[1]
    assert raised["status"] == "error" and not raised["converged"]
    assert raised["failed_checks"] == ["sampling_error"]
    assert "Initialization failed" in raised["reason"]
    assert raised["map"] is None and raised["diagnostics"] is None

    bad = recs[2]
    assert not bad["converged"] and "rhat" in bad["failed_checks"]
    assert bad["map"] is not None  # estimates are kept for inspection, not used in metrics
    assert "R-hat" in bad["reason"]

    const = recs[3]
    assert not const["converged"] and "kde" in const["failed_checks"]
    assert "zero spread" in const["reason"] and const["map"] is None

    nan = recs[4]
    assert not nan["converged"] and {"nonfinite", "kde"} <= set(nan["failed_checks"])
    assert "non-finite" in nan["reason"]

    rejected = recs[5]
    assert rejected["status"] == "error" and rejected["failed_checks"] == ["exception"]
    assert "data rejected" in rejected["reason"]


def test_resume_skips_valid_records(scenario):
    run(scenario, FakeBackend(MODES))
    mtimes = {k: record_path(scenario["records_dir"], k).stat().st_mtime_ns for k in range(K)}
    backend = FakeBackend(MODES)
    progress = Progress("t", total=K, logger=logging.getLogger("test"))
    recs = run(scenario, backend, progress=progress)
    assert backend.calls == [] and backend.compiled == []
    assert progress.done == K
    assert [r["converged"] for r in recs] == [True, False, False, False, False, False]
    assert mtimes == {
        k: record_path(scenario["records_dir"], k).stat().st_mtime_ns for k in range(K)
    }
    # changing only the number of workers keeps the records
    run(
        scenario,
        backend,
        sampler=SamplerSettings(chains=4, iter_warmup=100, iter_sampling=400, workers=2),
    )
    assert backend.calls == []


def test_interrupted_run_resumes_where_it_stopped(scenario):
    run(scenario, FakeBackend(), ks=[0, 1, 2])  # "killed" after three trajectories
    backend = FakeBackend()
    run(scenario, backend)
    assert [c["k"] for c in backend.calls] == [3, 4, 5]


def test_corrupted_or_stale_record_is_recomputed(scenario):
    run(scenario, FakeBackend())
    record_path(scenario["records_dir"], 2).write_text('{"k": 2, "conver')  # truncated
    stale = json.loads(record_path(scenario["records_dir"], 4).read_text())
    stale["key"]["program_hash"] = "0" * 16
    record_path(scenario["records_dir"], 4).write_text(json.dumps(stale))
    missing = json.loads(record_path(scenario["records_dir"], 5).read_text())
    del missing["q95"]
    record_path(scenario["records_dir"], 5).write_text(json.dumps(missing))
    backend = FakeBackend()
    recs = run(scenario, backend)
    assert [c["k"] for c in backend.calls] == [2, 4, 5]
    assert all(r["converged"] for r in recs)
    assert len(load_records(scenario["records_dir"], range(K))) == K


def _keeping_time(path, edit) -> None:
    """Apply ``edit`` (the parsed JSON, changed in place) to a record and restore its time."""
    import os

    st = path.stat()
    rec = json.loads(path.read_text())
    edit(rec)
    path.write_text(json.dumps(rec, indent=1, sort_keys=True) + "\n")
    os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns))


def test_a_record_edited_in_place_or_without_checksum_is_recomputed(scenario):
    """Found reused before (issue 35): a record edited into other valid JSON with its file
    time restored flowed into the tables; one without its checksum counts as damaged."""
    from ssmobs.nuts.record_cache import RECORD_CHECKSUM

    first = run(scenario, FakeBackend())
    records = scenario["records_dir"]
    _keeping_time(record_path(records, 1), lambda rec: rec["map"].__setitem__(0, 0.5))
    _keeping_time(record_path(records, 4), lambda rec: rec.pop(RECORD_CHECKSUM))
    backend = FakeBackend()
    again = run(scenario, backend)
    assert [c["k"] for c in backend.calls] == [1, 4]
    assert [r["map"] for r in again] == [r["map"] for r in first]


def test_changed_settings_program_or_data_recompute(scenario):
    run(scenario, FakeBackend(), ks=[0, 1])
    backend = FakeBackend()
    # a convergence threshold changes no draw: the tables apply it to the stored diagnostics
    run(scenario, backend, ks=[0, 1], convergence=ConvergenceSettings(rhat_max=1.05))
    assert backend.calls == []
    backend = FakeBackend()
    run(scenario, backend, ks=[0, 1], convergence=ConvergenceSettings(implementation="arviz"))
    assert [c["k"] for c in backend.calls] == [0, 1]
    scenario["stan_file"].write_text("// changed program\n")
    backend = FakeBackend()
    run(scenario, backend, ks=[0, 1], convergence=ConvergenceSettings(rhat_max=1.05))
    assert [c["k"] for c in backend.calls] == [0, 1]
    z = scenario["z"].copy()
    z[1, 3, 0] += 1.0
    backend = FakeBackend()
    run(scenario, backend, ks=[0, 1], z=z, convergence=ConvergenceSettings(rhat_max=1.05))
    assert [c["k"] for c in backend.calls] == [1]


def test_init_radius_recomputes_only_off_stans_default(scenario):
    """Records made before ``init_radius`` existed hold Stan's default 2: still valid."""
    run(scenario, FakeBackend(), ks=[0, 1])
    for radius, sampled in ((2.0, []), (0.5, [0, 1])):
        backend = FakeBackend()
        sampler = dataclasses.replace(scenario["sampler"], init_radius=radius)
        run(scenario, backend, ks=[0, 1], sampler=sampler)
        assert [c["k"] for c in backend.calls] == sampled


def test_one_stan_seed_for_every_trajectory(scenario):
    """Scenario key stan_seed: every k sampled with the same seed, keyed apart from the
    per-trajectory records (issue 20: the seed scheme of a loop with a fixed seed)."""
    backend = FakeBackend()
    run(scenario, backend, ks=[0, 1, 2])
    per_k = [c["seed"] for c in backend.calls]
    assert len(set(per_k)) == 3
    backend = FakeBackend()
    recs = run(scenario, backend, ks=[0, 1, 2], stan_seed=77)
    assert [c["seed"] for c in backend.calls] == [77, 77, 77]  # not the stored records
    assert {r["key"]["stan_seed"] for r in recs} == {77}


def test_chains_start_at_each_trajectorys_joint_map(scenario):
    """init "joint_map": every chain of trajectory k starts at its joint MAP (Omega, x0, x);
    where that is not finite or outside the prior's support, at Stan's random inits."""
    m, n_theta = 1, 1 + 1 + T
    theta = np.tile(np.linspace(0.5, 1.5, n_theta), (K, 1))
    theta[:, 0] = 0.8  # a inside (0, 1)
    theta[1, 3] = np.nan  # no point for k = 1
    theta[2, 0] = 1.0  # a on the bound for k = 2
    backend = FakeBackend()
    recs = run(scenario, backend, ks=[0, 1, 2], init="joint_map", init_theta=theta)
    first = backend.calls[0]["inits"]
    assert len(first) == SAMPLER.chains and first[0]["a"] == 0.8
    assert first[0]["x0"] == theta[0, m] and first[0]["x"] == theta[0, m + 1 :].tolist()
    assert backend.calls[1]["inits"] is None and backend.calls[2]["inits"] is None
    assert [r["init"] for r in recs] == ["joint_map", "joint_map: random", "joint_map: random"]
    assert "init_hash" in recs[0]["key"] and "init_hash" not in recs[1]["key"]
    # another joint MAP for k = 0 only: only k = 0 is sampled again
    theta[0, 2] += 0.1
    backend = FakeBackend()
    run(scenario, backend, ks=[0, 1, 2], init="joint_map", init_theta=theta)
    assert [c["k"] for c in backend.calls] == [0]
    with pytest.raises(ValueError, match="init_theta"):
        run(scenario, FakeBackend(), ks=[0], init="joint_map")


def test_retry_errors(scenario):
    run(scenario, FakeBackend({1: "raise"}), ks=[0, 1])
    backend = FakeBackend()
    recs = run(scenario, backend, ks=[0, 1])
    assert backend.calls == [] and not recs[1]["converged"]
    recs = run(scenario, backend, ks=[0, 1], retry_errors=True)
    assert [c["k"] for c in backend.calls] == [1] and recs[1]["converged"]


def test_true_inits_and_random_inits(scenario):
    backend = FakeBackend()
    run(scenario, backend, ks=[2])
    assert backend.calls[0]["inits"] is None
    backend = FakeBackend()
    run(scenario, backend, ks=[2], init="true")
    inits = backend.calls[0]["inits"]
    assert len(inits) == SAMPLER.chains
    assert inits[0] == {"a": 0.9, "x0": 8.0, "x": scenario["x_true"][2, :, 0].tolist()}
    with pytest.raises(ValueError):
        run(scenario, backend, ks=[2], init="zero")


def test_true_inits_for_two_states(tmp_path):
    from ssmobs.nuts.batch import _inits

    model = get_model("sep_d1_p2")
    x = np.arange(6.0).reshape(3, 2)
    inits = _inits(model, np.array([0.6, 0.5, 0.9, 0.9]), np.array([8, 7]), x, 2)
    assert inits[1] == {
        "a": 0.6,
        "b": 0.5,
        "c": 0.9,
        "d": 0.9,
        "x0": [8.0, 7.0],
        "x": [[0.0, 1.0], [2.0, 3.0], [4.0, 5.0]],
    }


def test_keep_draws_only_for_chosen_k(scenario):
    import xarray as xr

    run(scenario, FakeBackend(), keep_draws_for={0, 3})
    files = sorted(p.name for p in scenario["draws_dir"].iterdir())
    assert files == ["k00000.nc", "k00003.nc"]
    idata = xr.open_datatree(scenario["draws_dir"] / "k00003.nc", engine="h5netcdf")
    assert idata.posterior["x"].shape == (4, 400, T)
    assert idata.sample_stats["diverging"].dtype == bool
    assert idata.posterior.attrs["k"] == 3
    # a kept draws file that went missing is regenerated (same seed, same record)
    (scenario["draws_dir"] / "k00003.nc").unlink()
    backend = FakeBackend()
    run(scenario, backend, keep_draws_for={0, 3})
    assert [c["k"] for c in backend.calls] == [3]
    assert (scenario["draws_dir"] / "k00003.nc").exists()
    with pytest.raises(ValueError, match="draws_dir"):
        run(scenario, backend, keep_draws_for={0}, draws_dir=None)


def test_frame_and_summary_from_stage_records(scenario):
    recs = run(scenario, FakeBackend({2: "bad", 1: "raise"}))
    frame = records_to_frame(recs, scenario["model"], T)
    assert len(frame) == K and frame["converged"].sum() == 4
    # 7 record fields, 6 worst diagnostics, 3 x 3 per block (Omega, x0, states), 3 per Theta
    assert len(frame.columns) == 7 + 6 + 9 + 3 * (T + 2)
    assert frame.loc[1, "status"] == "error" and np.isnan(frame.loc[1, "a_map"])
    ok = frame[frame["status"] == "ok"]
    assert np.isfinite(ok[["max_rhat_omega", "min_ess_bulk_x0", "min_ess_tail_states"]]).all(None)
    assert (ok["max_rhat"] == ok[[f"max_rhat_{b}" for b in ("omega", "x0", "states")]].max(1)).all()
    out = stan_summary(frame, scenario["model"], [0.9], 8.0, scenario["x_true"])
    assert out["n_stan"] == 4 and out["ratio"] == pytest.approx(4 / 6)
    assert out["a_mean"] == pytest.approx(0.9, abs=0.01)
    assert "timings" not in " ".join(frame.columns)


def test_records_are_deterministic_apart_from_timings(scenario, tmp_path):
    a = run(scenario, FakeBackend(), ks=[0, 2])
    b = run(scenario, FakeBackend(), ks=[0, 2], records_dir=tmp_path / "again")
    for r1, r2 in zip(a, b):
        r1, r2 = dict(r1), dict(r2)
        r1.pop("timings"), r2.pop("timings")
        assert json.dumps(r1, sort_keys=True) == json.dumps(r2, sort_keys=True)


def test_realistic_size_record(scenario):
    """A T = 100 record (102 Theta components x 24 000 draws) has every component and its
    timings (the overhead target itself is measured in benchmarks/bench_nuts_stage.py)."""
    model = scenario["model"]
    z = np.random.default_rng(1).normal(0, 1, (1, 100, 1))
    z[0, 0, 0] = 0
    recs = run(
        scenario,
        FakeBackend(),
        ks=[0],
        z=z,
        x_true=z,
        sampler=SamplerSettings(chains=4, iter_warmup=10, iter_sampling=6000),
    )
    assert recs[0]["converged"]
    assert len(recs[0]["map"]) == len(model.theta_names(100))
    t = recs[0]["timings"]
    assert t["overhead"] >= t["diagnostics"] + t["marginal"] > 0, t


def test_backend_failure_fails_the_job_without_a_record(scenario):
    """An error that is not the sampler's on these data (here a bug) is never stored."""
    backend = FakeBackend({2: "bug"})
    with pytest.raises(ZeroDivisionError):
        run(scenario, backend)
    assert record_path(scenario["records_dir"], 1).exists()
    assert not record_path(scenario["records_dir"], 2).exists()


class OtherStanFake(FakeBackend):
    name = "other"

    def identity(self):
        return {"backend": self.name, "stan_version": "9.9"}


def test_switching_backend_recomputes_records(scenario):
    first = FakeBackend()
    run(scenario, first)
    assert len(first.calls) == K
    again = FakeBackend()
    run(scenario, again)
    assert again.calls == []  # same backend: every record reused
    other = OtherStanFake()
    recs = run(scenario, other)
    assert len(other.calls) == K
    assert {r["key"]["backend"] for r in recs} == {"other 9.9"}


# ------------------------------------------- issue 14: gather_nuts checks the records
@pytest.fixture()
def batch(scenario, tmp_path):
    """A batch of the Stan stage as on disk: records/k*.json and the batch table."""
    from ssmobs import io

    folder = tmp_path / "sample_nuts"
    recs = run(scenario, FakeBackend(), records_dir=folder / "records")
    table = folder / "batch0.parquet"
    frame = apply_thresholds(records_to_frame(recs, scenario["model"], T), ConvergenceSettings())
    io.write_parquet(table, frame)
    return table


def check(table, scenario):
    from ssmobs import io
    from ssmobs.nuts.record_cache import check_batch_records

    frame = io.read_parquet(table)
    check_batch_records(table, frame, scenario["model"], T, table.parent / "records", {})


def test_intact_records_pass_the_check(batch, scenario):
    check(batch, scenario)


@pytest.mark.parametrize(
    "damage,needle",
    [
        ("truncate", r"record of trajectory k=2 is damaged .*k00002.json: not valid JSON"),
        ("delete", r"record of trajectory k=2 .*k00002.json\) is missing"),
        ("edit", r"record of trajectory k=2 is damaged .*checksum is missing or does not match"),
        ("edit and checksum", r"records of trajectories k=\[2\] .* differ from it"),
        ("other_k", r"k00002.json is of trajectory k=3, not k=2"),
    ],
)
def test_damaged_record_names_the_batch_to_rerun(batch, scenario, damage, needle):
    from ssmobs import io

    path = batch.parent / "records" / "k00002.json"
    if damage == "truncate":
        path.write_text(path.read_text()[:100])
    elif damage == "delete":
        path.unlink()
    elif damage.startswith("edit"):
        from ssmobs.nuts.record_cache import write_record

        rec = json.loads(path.read_text())
        rec["map"][0] += 1.0
        if damage == "edit":
            path.write_text(json.dumps(rec))
        else:
            write_record(path, rec)
    else:
        path.write_text((batch.parent / "records" / "k00003.json").read_text())
    with pytest.raises(io.CorruptFileError, match=needle) as err:
        check(batch, scenario)
    msg = str(err.value)
    assert msg.startswith(f"{batch}: ")
    assert "this batch must be rerun" in msg and "delete this file and rerun" in msg


def test_records_changed_after_the_batch_table_are_found_by_file_times(batch):
    import os

    from ssmobs import io
    from ssmobs.nuts.record_cache import changed_batch_records

    records = batch.parent / "records"
    assert changed_batch_records(batch, records) is None
    assert changed_batch_records(batch.parent / "batch9.parquet", records) is None  # not run yet
    later = batch.stat().st_mtime_ns + 10**9
    os.utime(records / "k00004.json", ns=(later, later))  # e.g. truncated after the batch ran
    msg = changed_batch_records(batch, records)
    assert msg.startswith(f"{batch}: the record of trajectory k=4 ")
    assert "was changed after this table was written; this batch must be rerun" in msg
    # only the k the table was built from count (e.g. after a change of stan.batch_size)
    small = batch.parent / "batch1.parquet"
    io.write_parquet(small, io.read_parquet(batch).iloc[:3])
    os.utime(small, ns=(later - 10, later - 10))
    assert changed_batch_records(small, records) is None
    (records / "k00001.json").unlink()
    assert "trajectory k=1" in changed_batch_records(batch, records)
    assert "is missing" in changed_batch_records(batch, records)


def test_kept_draws_without_their_checksum_are_damaged(scenario, tmp_path):
    """Found passed before (issue 35): kept draws whose record holds no checksum counted
    as intact."""
    from ssmobs import io
    from ssmobs.nuts.record_cache import changed_batch_records, read_record, write_record

    folder = tmp_path / "sample_nuts"
    recs = run(scenario, FakeBackend(), records_dir=folder / "records", keep_draws_for={0})
    table = folder / "batch0.parquet"
    io.write_parquet(table, records_to_frame(recs, scenario["model"], T))
    records, draws = folder / "records", scenario["draws_dir"]
    assert changed_batch_records(table, records, draws, {0}) is None
    path = record_path(records, 0)
    rec = read_record(path)
    del rec["draws_sha256"]
    st = table.stat()
    write_record(path, rec)
    os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns))  # its time: not newer than the table
    assert "kept draws" in changed_batch_records(table, records, draws, {0})
    backend = FakeBackend()
    run(scenario, backend, records_dir=records, keep_draws_for={0})
    assert [c["k"] for c in backend.calls] == [0]


def test_thresholds_are_applied_to_stored_diagnostics_with_the_failing_block(scenario):
    """A table under other thresholds needs no sampling, and says which block failed."""
    recs = run(scenario, FakeBackend())
    frame = records_to_frame(recs, scenario["model"], T)
    strict = apply_thresholds(frame, ConvergenceSettings(ess_bulk_min=1e9))
    assert not strict["converged"].any()
    assert all("ess_bulk" in c.split(",") for c in strict["failed_checks"])
    assert all("ess_bulk: min bulk-ESS" in r for r in strict["reason"])
    assert set(strict["failing_blocks"]) == {"omega,x0,states"}
    loose = apply_thresholds(strict, ConvergenceSettings(ess_bulk_min=1.0, ess_tail_min=1.0))
    assert loose["converged"].all() and set(loose["failing_blocks"]) == {""}
    assert set(loose["reason"]) == {""}


class _Sampled(Exception):
    """Raised by the stub of run_trajectories: the job got as far as sampling."""


def write_marker(path, model, header=None):
    """A build job's marker of ``model``'s hand-written program (and ``header``)."""
    from ssmobs.stan_backends import stan_file

    marker = {"backend": "native", "program_file": str(stan_file(model))}
    path.write_text(json.dumps({**marker, "header_file": None if header is None else str(header)}))


def _batch_inputs(tmp_path, entry=None, **stan):
    """The inputs of batch 1 (k = 2, 3) of a Same scenario whose trajectories, program's
    marker and folders lie in ``tmp_path``."""
    from ssmobs.config.scenario import Scenario
    from ssmobs.config.stage_inputs import nuts_batches_inputs
    from ssmobs.design.trajectories import make_trajectories, write_trajectories

    sc = Scenario.from_config(same_a09(T=3))
    write_trajectories(tmp_path / "t.nc", make_trajectories(sc, np.zeros((6, 4))))
    write_marker(tmp_path / "marker.json", "same")
    stan_cfg = {
        "batch_size": 2,
        "keep_draws": [],
        "chains": 1,
        "iter_warmup": 10,
        "iter_sampling": 10,
        "adapt_delta": 0.8,
        "max_treedepth": 10,
        **stan,
    }
    entry = {**same_a09(T=3), "name": sc.name, "K": 4, "seed": sc.seed, "stan_init": "random"}
    return nuts_batches_inputs(
        entry,
        {"stan": stan_cfg, "convergence": {"rhat_max": 1.05, "implementation": "arviz"}},
        trajectories=str(tmp_path / "t.nc"),
        program_marker=str(tmp_path / "marker.json"),
        joint_map="unused",
        own_program=True,
        records=str(tmp_path / "records"),
        batch_size=2,
    )


def test_a_batch_job_writes_no_program_and_samples_as_its_records_are_keyed(tmp_path, monkeypatch):
    """Issue 62: a NUTS batch runs the program its build job's marker names (it writes none:
    generating one fails here) with exactly the settings its records are keyed by."""
    import ssmobs.nuts.analytic_program
    import ssmobs.nuts.batch
    import ssmobs.nuts.stan_program
    from ssmobs.stages.stan import run_sample_batch

    def refuse(*args, **kwargs):
        raise AssertionError("a NUTS batch job wrote a Stan program")

    for module, name in [
        (ssmobs.nuts.stan_program, "stan_program"),
        (ssmobs.nuts.stan_program, "write_analytic_program"),
        (ssmobs.nuts.analytic_program, "write_analytic_program"),
    ]:
        monkeypatch.setattr(module, name, refuse)
    seen = []

    def sample(batch, backend, ks, **kwargs):
        seen.append((batch, backend.name, list(ks), kwargs))
        raise _Sampled

    monkeypatch.setattr(ssmobs.nuts.batch, "run_trajectories", sample)
    inputs = _batch_inputs(tmp_path, init_radius=0.5, adapt_delta=0.9, gradients="analytic")
    header = tmp_path / "same_analytic.hpp"
    header.write_text("// the generated gradient")
    write_marker(tmp_path / "marker.json", "same", header)
    with pytest.raises(_Sampled):
        run_sample_batch(inputs, {"table": tmp_path / "batch1.parquet"})
    ((batch, backend, ks, kwargs),) = seen
    record = inputs.record
    assert (backend, ks) == ("native", [2, 3])
    assert json.loads((tmp_path / "marker.json").read_text())["program_file"] == str(
        batch.stan_file
    )
    assert batch.user_header == header
    assert batch.sampler == SamplerSettings(
        chains=1, iter_warmup=10, iter_sampling=10, adapt_delta=0.9, init_radius=0.5
    )
    assert dict(record.sampler) == {
        k: v for k, v in dataclasses.asdict(batch.sampler).items() if k != "workers"
    }
    assert (batch.scenario, batch.seed, batch.init) == (record.scenario, record.seed, "random")
    assert batch.convergence == ConvergenceSettings(rhat_max=1.05, implementation="arviz")
    assert record.diagnostics == "arviz"
    assert kwargs["records_dir"] == inputs.records and kwargs["keep_draws_for"] == set()
    # a program built for another gradient path than the records are keyed by is refused
    autodiff = _batch_inputs(tmp_path)
    write_marker(tmp_path / "marker.json", "same", header)
    with pytest.raises(ValueError, match="autodiff gradients, but the program"):
        run_sample_batch(autodiff, {"table": tmp_path / "batch1.parquet"})
    # a marker whose program is gone (the program cache cleared) stops the job in one line
    header.unlink()
    with pytest.raises(
        FileNotFoundError, match="marker.json names is gone .*run the workflow again"
    ):
        run_sample_batch(inputs, {"table": tmp_path / "batch1.parquet"})


def test_batch_job_sweeps_its_records_temporaries_in_the_shared_folders(tmp_path, monkeypatch):
    """A killed sample_nuts job leaves temporaries of single records and draws in the folders
    all batches share; the next job of that batch removes its own, not other batches'."""
    import ssmobs.nuts.batch
    from ssmobs.stages.stan import run_sample_batch

    records, draws = tmp_path / "records", tmp_path / "draws"
    records.mkdir()
    draws.mkdir()
    ours = [records / ".k00002.json.abcd1234.json", draws / ".k00003.nc.abcd1234.nc"]
    other = records / ".k00000.json.abcd1234.json"  # batch 0's: its job may be running
    for path in [*ours, other]:
        path.write_text("half written")

    def stub(*args, **kwargs):
        raise _Sampled

    monkeypatch.setattr(ssmobs.nuts.batch, "run_trajectories", stub)
    inputs = _batch_inputs(tmp_path)
    inputs = dataclasses.replace(inputs, draws=str(draws))
    assert inputs.batch_of("batch1.parquet") == (2, 3)
    with pytest.raises(_Sampled):
        run_sample_batch(inputs, {"table": tmp_path / "batch1.parquet"})
    assert not any(p.exists() for p in ours)
    assert other.exists()


def test_a_damaged_record_that_is_recomputed_is_not_said_to_need_deleting(tmp_path, caplog):
    """Issue 46: while a damaged record was recomputed, the warning still said "delete this
    file and rerun"."""
    from ssmobs.nuts.record_cache import load_record, write_record

    path = tmp_path / "k00000.json"
    write_record(path, {"record_version": 1, "a": 1.0})
    path.write_text(path.read_text().replace("1.0", "2.0"))
    with caplog.at_level(logging.WARNING):
        assert load_record(path) is None
    (line,) = [r.getMessage() for r in caplog.records if "recomputing" in r.getMessage()]
    assert line.startswith(f"recomputing: {path}: missing keys")
    assert "delete this file" not in line
