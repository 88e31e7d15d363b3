"""Config validation: all profiles pass, every bad value gets one clear message."""

from __future__ import annotations

import copy

import pytest
import yaml
from factories import same_a09
from repo_paths import REPO_DIR
from ssmobs.config import validation as cfg

pytestmark = pytest.mark.unit

#: every profile of config/ (paper_values.yaml holds the paper's numbers, not a profile)
PROFILES = sorted(
    p.relative_to(REPO_DIR / "config").as_posix()
    for p in [
        *(REPO_DIR / "config").glob("*.yaml"),
        *(REPO_DIR / "config").glob("section4_rows/*.yaml"),
        *(REPO_DIR / "config").glob("stan_variants/*.yaml"),
    ]
    if p.name != "paper_values.yaml"
)


def load(name: str) -> dict:
    return yaml.safe_load((REPO_DIR / "config" / name).read_text())


@pytest.mark.parametrize("name", PROFILES)
def test_profiles_validate_and_get_defaults(name):
    c = cfg.validate(load(name))
    assert c["stan"]["backend"] == "auto"
    assert c["joint_map"]["grad_tol"] == 1e-5
    assert c["joint_map"]["eig_ratio_min"] == 1e-5
    assert c["convergence"]["rhat_max"] == 1.01
    for sc in c["scenarios"]:
        assert sc["method"] in ("design", "random", "antithetic")
        assert isinstance(sc["seed"], int)


def base() -> dict:
    return {"scenarios": [same_a09(K=10)]}


def with_(path, value):
    c = base()
    target = c
    for key in path[:-1]:
        target = target[key]
    target[path[-1]] = value
    return c


BAD = [
    (
        "unknown model",
        with_(["scenarios", 0, "model"], "nope"),
        ["scenarios[0]", "model", "nope", "same"],
    ),
    ("unknown prior", with_(["scenarios", 0, "prior"], "flat"), ["flat", "restricted"]),
    ("prior not allowed", with_(["scenarios", 0, "prior"], "half_line"), ["half_line", "allowed"]),
    ("K zero", with_(["scenarios", 0, "K"], 0), ["scenarios[0].K", "0", ">= 1"]),
    ("K negative", with_(["scenarios", 0, "K"], -3), ["scenarios[0].K", "-3", ">= 1"]),
    ("K not integer", with_(["scenarios", 0, "K"], 2.5), ["scenarios[0].K", "2.5", "integer"]),
    ("T zero", with_(["scenarios", 0, "T"], 0), ["scenarios[0].T", "0", ">= 1"]),
    ("|a| >= 1", with_(["scenarios", 0, "omega"], {"a": 1.2}), ["a=1.2", "|a| < 1"]),
    ("a outside restricted prior", with_(["scenarios", 0, "omega"], {"a": 0.0}), ["a", "0"]),
    (
        "seed not integer",
        with_(["scenarios", 0, "seed"], "abc"),
        ["scenarios[0].seed", "abc", "integer"],
    ),
    (
        "negative threshold",
        {**base(), "joint_map": {"grad_tol": -1.0}},
        ["joint_map.grad_tol", "-1.0", "> 0"],
    ),
    (
        "negative ess",
        {**base(), "convergence": {"ess_bulk_min": -5}},
        ["convergence.ess_bulk_min", "-5", ">= 0"],
    ),
    ("unknown key", with_(["scenarios", 0, "colour"], "red"), ["colour"]),
    ("missing x0 entry", with_(["scenarios", 0, "omega"], {"b": 0.5}), ["'a'", "missing"]),
]


@pytest.mark.parametrize("label,conf,needles", BAD, ids=[b[0] for b in BAD])
def test_bad_values_named(label, conf, needles):
    with pytest.raises(cfg.ConfigError) as err:
        cfg.validate(copy.deepcopy(conf))
    msg = str(err.value)
    for needle in needles:
        assert needle in msg, f"{needle!r} not in message: {msg}"


def test_sep_d1_p2_needs_a2_plus_b2_below_one():
    c = base()
    c["scenarios"][0].update(
        model="sep_d1_p2", omega={"a": 0.8, "b": 0.7, "c": 0.9, "d": 0.9}, x0=[8, 8]
    )
    with pytest.raises(cfg.ConfigError, match=r"a\^2 \+ b\^2 < 1"):
        cfg.validate(c)


def test_half_line_prior_needs_positive_true_value_in_mult():
    c = base()
    c["scenarios"][0].update(model="sep_mult", omega={"a": -0.5})
    with pytest.raises(cfg.ConfigError, match="must be > 0"):
        cfg.validate(c)


def test_duplicate_scenario_names():
    c = base()
    c["scenarios"].append(copy.deepcopy(c["scenarios"][0]))
    with pytest.raises(cfg.ConfigError, match="used twice"):
        cfg.validate(c)


def test_k_grid_must_increase():
    c = base()
    c["k_selection"] = [{"name": "k", "scenario": "s", "K_grid": [10, 30, 20]}]
    with pytest.raises(cfg.ConfigError, match="strictly increasing"):
        cfg.validate(c)


def test_k_selection_unknown_scenario():
    c = base()
    c["k_selection"] = [{"name": "k", "scenario": "zzz", "K_grid": [10, 20]}]
    with pytest.raises(cfg.ConfigError, match="zzz"):
        cfg.validate(c)


def test_x0_dimension_checked():
    c = with_(["scenarios", 0, "x0"], [1.0, 2.0])
    with pytest.raises(cfg.ConfigError, match="x0 must have 1 component"):
        cfg.validate(c)


def test_cmdstanpy_backend_without_cmdstan_is_refused():
    from ssmobs.stan_backends import have_cmdstan

    if have_cmdstan():
        pytest.skip("CmdStan is installed here, so the cmdstanpy backend is valid")
    c = {**base(), "stan": {"backend": "cmdstanpy"}}
    with pytest.raises(cfg.ConfigError, match=r"stan.backend = 'cmdstanpy'.*CmdStan.*'pystan'"):
        cfg.validate(c)


def test_unknown_backend_name():
    with pytest.raises(cfg.ConfigError, match=r"stan.backend = 'stan'.*allowed values"):
        cfg.validate({**base(), "stan": {"backend": "stan"}})


# ----------------------------------------------------------------- issue 14: silent wrong answers
def number_keys(schema: dict, path: tuple = ()) -> list[tuple]:
    """Every key the schema types as a number (also in lists of objects), as a config path."""
    out = []
    kinds = schema.get("type")
    kinds = kinds if isinstance(kinds, list) else [kinds]
    if "number" in kinds:
        out.append(path)
    for key, sub in schema.get("properties", {}).items():
        out += number_keys(sub, path + (key,))
    if isinstance(schema.get("items"), dict) and schema["items"].get("type") == "object":
        out += number_keys(schema["items"], path + (0,))
    return out


def full_config() -> dict:
    """base() with every optional section present, so each number key has a place to go."""
    c = base()
    c["k_selection"] = [{"name": "k", "scenario": "s", "K_grid": [10, 20]}]
    sections = (
        "figure2",
        "figure4",
        "design",
        "joint_map",
        "stan",
        "convergence",
        "exact_marginal",
    )
    for section in (*sections, "limits"):
        c[section] = {}
    c["scenarios"][0]["stan_settings"] = {}  # a scenario's own NUTS settings (issue 20)
    return c


NUMBER_KEYS = number_keys(cfg.load_schema())


def test_schema_has_the_numbers_of_the_issue():
    names = {".".join(map(str, p)) for p in NUMBER_KEYS}
    for key in (
        "convergence.ess_bulk_min",
        "stan.adapt_delta",
        "convergence.rhat_max",
        "k_selection.0.c1",
        "joint_map.grad_tol",
        "figure2.a",
        "limits.job_memory_gib",
    ):
        assert key in names


@pytest.mark.parametrize(
    "value", [float("nan"), float("inf"), float("-inf")], ids=["nan", "inf", "-inf"]
)
@pytest.mark.parametrize("path", NUMBER_KEYS, ids=[".".join(map(str, p)) for p in NUMBER_KEYS])
def test_every_number_key_must_be_finite(path, value):
    c = full_config()
    target = c
    for key in path[:-1]:
        target = target[key]
    target[path[-1]] = value
    with pytest.raises(cfg.ConfigError, match="must be a finite number") as err:
        cfg.validate(c)
    key = "".join(f"[{p}]" if isinstance(p, int) else f".{p}" for p in path).lstrip(".")
    assert f"{key} = {value!r}" in str(err.value)


@pytest.mark.parametrize("where", [("scenarios", 0, "omega", "a"), ("scenarios", 0, "x0")])
def test_nan_in_true_values_refused(where):
    c = base()
    target = c
    for key in where[:-1]:
        target = target[key]
    target[where[-1]] = float("nan")
    with pytest.raises(cfg.ConfigError, match="must be a finite number"):
        cfg.validate(c)


def test_yaml_nan_from_a_config_file_refused():
    c = yaml.safe_load("convergence: {ess_bulk_min: .nan}\nstan: {adapt_delta: .inf}\n")
    c.update(base())
    with pytest.raises(cfg.ConfigError) as err:
        cfg.validate(c)
    assert "convergence.ess_bulk_min = nan" in str(err.value)
    assert "stan.adapt_delta = inf" in str(err.value)


@pytest.mark.parametrize("a", [1.5, 1.0, -1.0, -2.0])
def test_figure2_a_outside_the_stationary_range_refused(a):
    with pytest.raises(cfg.ConfigError, match=rf"figure2.a = {a}"):
        cfg.validate({**base(), "figure2": {"a": a}})


def test_figure2_a_inside_range_accepted():
    assert cfg.validate({**base(), "figure2": {"a": -0.5}})["figure2"]["a"] == -0.5


def test_figure4_empty_grid_refused():
    with pytest.raises(cfg.ConfigError, match="figure4.a_min = 2.0, figure4.a_max = 1.0"):
        cfg.validate({**base(), "figure4": {"a_min": 2.0, "a_max": 1.0}})


def test_keep_draws_beyond_K_refused():
    with pytest.raises(cfg.ConfigError, match=r"stan.keep_draws = \[0, 999\]: k = \[999\]"):
        cfg.validate({**base(), "stan": {"keep_draws": [0, 999]}})
    with pytest.raises(cfg.ConfigError, match=r"k = \[10\]"):  # k counts from 0: K = 10
        cfg.validate({**base(), "stan": {"keep_draws": [10]}})
    assert cfg.validate({**base(), "stan": {"keep_draws": [9]}})["stan"]["keep_draws"] == [9]


def test_keep_draws_checked_against_the_largest_stan_scenario():
    c = base()
    c["scenarios"].append({**c["scenarios"][0], "name": "big", "K": 50})
    c["stan"] = {"keep_draws": [40]}  # only 'big' has k = 40: kept there
    cfg.validate(copy.deepcopy(c))
    c["scenarios"][1]["stan"] = False  # now no Stan scenario has it
    with pytest.raises(cfg.ConfigError, match="largest K is 10"):
        cfg.validate(c)


@pytest.mark.parametrize("name", ["shared", "k_selection", "Shared", "checksums"])
def test_reserved_scenario_names(name):
    c = with_(["scenarios", 0, "name"], name)
    with pytest.raises(cfg.ConfigError, match=rf"name = '{name}': reserved"):
        cfg.validate(c)


@pytest.mark.parametrize("section", ["scenario", "k_selection", "figure2"])
def test_seeds_bounded_to_32_bits(section):
    def conf(seed):
        c = base()
        if section == "scenario":
            c["scenarios"][0]["seed"] = seed
        elif section == "k_selection":
            c["k_selection"] = [
                {"name": "k", "scenario": "s", "K_grid": [10, 20], "seeds": [1, seed]}
            ]
        else:
            c["figure2"] = {"seed": seed}
        return c

    cfg.validate(conf(2**32 - 1))
    with pytest.raises(cfg.ConfigError, match="must be <= 4294967295"):
        cfg.validate(conf(2**70))


def test_seed_checked_where_it_is_read():
    from ssmobs import seeds

    assert seeds.int_seed(2**32 - 1, "nuts", "s", 0) >= 0
    with pytest.raises(ValueError, match=r"seed must be an integer in \[0, 4294967295\]"):
        seeds.int_seed(2**70, "nuts", "s", 0)


def test_top_level_not_a_mapping():
    with pytest.raises(cfg.ConfigError, match="top level must be a mapping"):
        cfg.validate(["scenarios"])


# ----------------------------------------------------------------- issue 14: runaway sizes
def huge() -> dict:
    return with_(
        ["scenarios", 0],
        same_a09(name="huge", T=1000, K=10_000_000),
    )


def test_runaway_size_refused_naming_scenario_estimate_and_limit():
    with pytest.raises(cfg.ConfigError) as err:
        cfg.validate(huge())
    msg = str(err.value)
    assert "scenario 'huge': a design_disturbances job needs about" in msg
    assert "K = 10000000, T = 1000, q = 2000" in msg
    assert "limits.job_memory_gib = 10 GiB" in msg
    assert "more than limits.jobs = 20000" in msg
    gib = float(msg.split("design_disturbances job needs about ")[1].split(" GiB")[0])
    assert gib > 74.5  # at least the (q x K) matrix the design stage would allocate


def test_raised_limits_accept_it_and_accept_strings_from_the_command_line():
    c = huge()
    # as --config passes them
    c["limits"] = {"job_memory_gib": "100000", "jobs": "1000000", "joint_map_cpu_hours": "1e6"}
    c["stan"] = {"batch_size": 1000}
    limits = {"job_memory_gib": 100000, "jobs": 1000000, "joint_map_cpu_hours": 1e6}
    assert cfg.validate(c)["limits"] == limits


def test_too_many_jobs_refused_even_when_memory_fits():
    c = with_(["scenarios", 0, "K"], 100_000)
    c["scenarios"][0]["T"] = 1
    c["stan"] = {"batch_size": 1}
    with pytest.raises(cfg.ConfigError) as err:
        cfg.validate(c)
    msg = str(err.value)
    assert "job needs about" not in msg
    assert "about 100017 jobs, more than limits.jobs = 20000" in msg
    # 2 checks, trajectories, joint MAP, 100 000 Stan batches, gather, exact stage and figure
    assert "scenario 's': 100007" in msg


def test_slurm_profile_raises_the_limits():
    profile = yaml.safe_load((REPO_DIR / "config/profiles/slurm/config.yaml").read_text())
    limits = profile["config"]["limits"]
    schema = cfg.load_schema()["properties"]["limits"]["properties"]
    assert limits["job_memory_gib"] > schema["job_memory_gib"]["default"]
    assert limits["jobs"] > schema["jobs"]["default"]


def test_schema_seed_bound_is_the_one_the_readers_check():
    from ssmobs.seeds import MAX_SEED

    props = cfg.load_schema()["properties"]
    assert props["scenarios"]["items"]["properties"]["seed"]["maximum"] == MAX_SEED
    assert props["k_selection"]["items"]["properties"]["seeds"]["items"]["maximum"] == MAX_SEED
    assert props["figure2"]["properties"]["seed"]["maximum"] == MAX_SEED


# ---------------------------------------------------------------- paper_outputs (issue 13)
def with_paper_outputs(**chosen) -> dict:
    c = base()
    c["scenarios"].append(
        {
            "name": "walk",
            "model": "sep_ranwalk",
            "omega": {"a": 0.9},
            "x0": 8,
            "T": 4,
            "K": 10,
            "stan": False,
        }
    )
    c["paper_outputs"] = chosen
    return c


@pytest.mark.parametrize(
    "key,value", [("tables_2_3", ["s", "nope"]), ("figure3", ["nope"]), ("figure4", "nope")]
)
def test_paper_outputs_unknown_name_is_refused_naming_the_key(key, value):
    with pytest.raises(cfg.ConfigError) as err:
        cfg.validate(with_paper_outputs(**{key: value}))
    msg = str(err.value)
    assert f"paper_outputs.{key}" in msg and "nope" in msg and "'s'" in msg


def test_paper_outputs_need_what_the_table_or_figure_shows():
    with pytest.raises(cfg.ConfigError, match=r"paper_outputs.tables_2_3.*\['walk'\].*both"):
        cfg.validate(with_paper_outputs(tables_2_3=["walk"]))
    with pytest.raises(cfg.ConfigError, match=r"paper_outputs.figure3.*one model"):
        c = with_paper_outputs(figure3=["s", "s2"])
        c["scenarios"].append({**c["scenarios"][0], "name": "s2", "omega": {"a": 0.7}})
        cfg.validate(c)
    c = with_paper_outputs(figure4="sv")
    c["scenarios"].append(
        {
            "name": "sv",
            "model": "stoch_vol",
            "x0": 0,
            "T": 5,
            "K": 4,
            "omega": {"phi": 0.9, "sigma": 0.5},
        }
    )
    with pytest.raises(cfg.ConfigError, match=r"paper_outputs.figure4.*2 parameter"):
        cfg.validate(c)
    ok = cfg.validate(with_paper_outputs(tables_2_3=["s"], figure3=["s"], figure4="walk"))
    assert ok["paper_outputs"] == {"tables_2_3": ["s"], "figure3": ["s"], "figure4": "walk"}
    assert cfg.validate(base())["paper_outputs"] == {
        "tables_2_3": [],
        "figure3": [],
        "figure4": None,
    }


@pytest.mark.parametrize(
    "name", ["config.yaml", "smoke.yaml", "paper.yaml", "tables.yaml", "section4_sep_d2_p1.yaml"]
)
def test_profiles_name_the_scenarios_of_the_papers_outputs(name):
    """Chosen by name: the rows of Tables II/III are the paper's Same (0.9, 8) scenarios."""
    c = cfg.validate(load(name))
    chosen = c["paper_outputs"]
    by_name = {sc["name"]: sc for sc in c["scenarios"]}
    for n in chosen["tables_2_3"] + chosen["figure3"]:
        assert (by_name[n]["model"], by_name[n]["omega"], by_name[n]["x0"]) == (
            "same",
            {"a": 0.9},
            8,
        )
    assert chosen["figure3"] == chosen["tables_2_3"]
    assert (chosen["figure4"] is None) == (
        "sep_ranwalk" not in {sc["model"] for sc in c["scenarios"]}
    )


# ------------------------------------------------- configs that silently mean something else
def refused(conf: dict) -> str:
    with pytest.raises(cfg.ConfigError) as err:
        cfg.validate(conf)
    return str(err.value)


@pytest.mark.parametrize(
    "path,value,key",
    [
        (("scenarios", 0, "K"), 12.0, "scenarios[0].K = 12.0"),
        (("scenarios", 0, "T"), 4.0, "scenarios[0].T = 4.0"),
        (("scenarios", 0, "seed"), 1.0, "scenarios[0].seed = 1.0"),
        (("scenarios", 0, "stan_batch_size"), 5.0, "scenarios[0].stan_batch_size = 5.0"),
        (("stan", "chains"), 4.0, "stan.chains = 4.0"),
        (("figure2", "K"), 5.0, "figure2.K = 5.0"),
        (("k_selection", 0, "K_grid"), [10.0, 20], "k_selection[0].K_grid[0] = 10.0"),
    ],
    ids=lambda p: ".".join(map(str, p)) if isinstance(p, tuple) else None,
)
def test_float_for_an_integer_key_refused(path, value, key):
    c = full_config()
    target = c
    for part in path[:-1]:
        target = target[part]
    target[path[-1]] = value
    msg = refused(c)
    whole = int(value[0] if isinstance(value, list) else value)
    assert f"{key}: must be a whole number written without a decimal point ({whole})" in msg


def test_unknown_paper_ref_refused_naming_the_known_keys():
    msg = refused(with_(["scenarios", 0, "paper_ref"], "same_a09_T2"))
    assert "scenarios[0] ('s').paper_ref = 'same_a09_T2': no such key in config/paper_values" in msg
    assert "'same_a09_T20'" in msg and "'' (none)" in msg
    assert cfg.validate(with_(["scenarios", 0, "paper_ref"], "same_a09_T20"))
    assert cfg.validate(with_(["scenarios", 0, "paper_ref"], ""))


def test_mu0_sweep_unknown_model_refused():
    msg = refused({**base(), "mu0_sweep": {"models": ["sep", "nope"]}})
    assert "mu0_sweep.models = ['sep', 'nope']: unknown model(s) ['nope']" in msg
    assert "'sep_d2_p1'" in msg  # the allowed models are listed
    # a known model no scenario uses only adds no rows (the default names Sep models)
    assert cfg.validate({**base(), "mu0_sweep": {"models": ["sep_mult"]}})


def mult(**entry) -> dict:
    c = base()
    c["scenarios"][0].update(model="sep_mult", omega={"a": 0.5}, prior="half_line", **entry)
    return c


def test_explicit_exact_true_on_a_model_not_linear_in_the_states_refused():
    msg = refused(mult(exact=True))
    assert "scenarios[0] ('s').exact = True: model 'sep_mult' is not linear in the states" in msg
    assert "exact: false" in msg
    assert "exact" not in cfg.validate(mult())["scenarios"][0]  # the default: not applicable
    assert cfg.validate(mult(exact=False))["scenarios"][0]["exact"] is False
    assert cfg.validate(with_(["scenarios", 0, "exact"], True))  # model same: linear


@pytest.mark.parametrize("value", ["../x", "/abs/path", "a/../../b", "paper_figures/..", ".."])
def test_outputs_dir_outside_the_working_directory_refused(value):
    msg = refused({**base(), "outputs_dir": value})
    assert f"outputs_dir = {value!r}: must be a relative path inside the working directory" in msg


@pytest.mark.parametrize("value", ["paper_figures/mine", "out", "a/b..c/d", "./x"])
def test_outputs_dir_inside_the_working_directory_accepted(value):
    assert cfg.validate({**base(), "outputs_dir": value})["outputs_dir"] == value


@pytest.mark.parametrize("value", [".git", "config", "results/x", "./workflow", ".", "stan/"])
def test_outputs_dir_in_a_folder_of_the_workflow_refused(value):
    """Issue 35: outputs_dir .git, config or results were accepted."""
    msg = refused({**base(), "outputs_dir": value})
    assert f"outputs_dir = {value!r}: would write into" in msg and "allowed: a folder" in msg


@pytest.mark.parametrize(
    ("link", "target", "shown"),
    [
        ("paper_figures/mine", "../results", "results, inside results/"),
        ("paper_figures/mine", "../results/stages", "results/stages, inside results/"),
        ("out", "results", "results, inside results/"),
        ("paper_figures", ".snakemake", ".snakemake/mine, inside .snakemake/"),
        ("paper_figures/mine", "..", "., the working directory itself"),
    ],
)
def test_outputs_dir_that_resolves_into_a_folder_of_the_workflow_refused(
    tmp_path, monkeypatch, link, target, shown
):
    """Issue 61 item 8: an outputs_dir linked into results/ was accepted and the tables
    landed beside the stages' folders."""
    monkeypatch.chdir(tmp_path)
    for folder in ("results/stages", ".snakemake"):
        (tmp_path / folder).mkdir(parents=True)
    (tmp_path / link).parent.mkdir(parents=True, exist_ok=True)
    (tmp_path / link).symlink_to(target)
    value = "out" if link == "out" else "paper_figures/mine"
    lines = refused({**base(), "outputs_dir": value}).splitlines()
    assert len(lines) == 2
    assert lines[1] == (
        f"  - outputs_dir = {value!r}: resolves (symbolic links followed) to {shown}, which "
        f"holds the workflow, its cache or git's data; allowed: a folder that resolves outside "
        f"{', '.join(sorted(cfg.RESERVED_DIRS))} (e.g. paper_figures/mine)"
    )


def test_outputs_dir_linked_elsewhere_in_the_working_directory_accepted(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "elsewhere").mkdir()
    (tmp_path / "paper_figures").mkdir()
    (tmp_path / "paper_figures" / "mine").symlink_to("../elsewhere")
    config = {**base(), "outputs_dir": "paper_figures/mine"}
    assert cfg.validate(config)["outputs_dir"] == "paper_figures/mine"


def test_a_name_longer_than_a_file_name_can_hold_refused():
    """Issue 35: a 300-character scenario name passed and failed the run (file name too long)."""
    c = base()
    c["scenarios"][0]["name"] = "s" * 101
    msg = refused(c)
    assert "scenarios[0].name" in msg and "101 characters; allowed: at most 100" in msg
    c["scenarios"][0]["name"] = "s" * 100
    assert cfg.validate(c)


def test_scenario_names_differing_only_in_case_refused():
    c = base()
    c["scenarios"].append({**c["scenarios"][0], "name": "S"})
    msg = refused(c)
    assert "scenarios[1] ('S').name = 'S': differs from scenarios[0] ('s') only in case" in msg
    c = base()
    c["k_selection"] = [
        {"name": n, "scenario": "s", "K_grid": [10, 20]} for n in ("same_T4", "SAME_T4")
    ]
    assert "k_selection[1] ('SAME_T4').name = 'SAME_T4': differs from" in refused(c)


@pytest.mark.parametrize("section", ["scenarios", "k_selection"])
def test_name_with_a_trailing_dot_refused(section):
    c = base()
    if section == "scenarios":
        c["scenarios"][0]["name"] = "s."
        c["scenarios"].append({**c["scenarios"][0], "name": "t"})
    else:
        c["k_selection"] = [{"name": "k.", "scenario": "s", "K_grid": [10, 20]}]
    msg = refused(c)
    assert f"{section}[0] (" in msg and ": ends with '.'" in msg


def test_long_values_are_cut_in_messages():
    msg = refused(with_(["scenarios", 0, "K"], "x" * 100_000))
    assert "scenarios[0].K = 'xxxx" in msg and "(100002 characters)" in msg
    assert "must be of type integer" in msg
    assert len(msg) < 600


def test_alias_expansion_of_a_million_values_refused_quickly():
    import time

    row = [1] * 1000
    c = base()
    c["stan"] = {"keep_draws": [row] * 1000}  # what YAML aliases give: one list, 1000 uses
    start = time.perf_counter()
    msg = refused(c)
    assert time.perf_counter() - start < 5
    assert "more than 100000 values" in msg and len(msg) < 300


def test_oneof_failure_names_the_item_of_the_matching_form():
    c = base()
    c["k_selection"] = [{"name": "k", "scenario": "s", "K_grid": [0, 8]}]
    msg = refused(c)
    assert "k_selection[0].K_grid[0] = 0: must be >= 1" in msg
    assert "one of the forms" not in msg
    c["k_selection"][0]["K_grid"] = {"step": 0, "last": 8}
    assert "k_selection[0].K_grid.step = 0: must be >= 1" in refused(c)
    assert "scenarios[0].x0[1] = 'a': must be of type number" in refused(
        with_(["scenarios", 0, "x0"], [1.0, "a"])
    )
    assert "scenarios[0].x0 = True: must be one of the forms ['number', 'array']" in refused(
        with_(["scenarios", 0, "x0"], True)
    )


@pytest.mark.parametrize(
    "path,value,message",
    [
        (
            ("scenarios", 0, "stan_init"),
            True,
            "scenarios[0].stan_init = True: allowed values are ['random', 'true', 'joint_map'] "
            "(write 'true' in quotes: unquoted, YAML reads true as a boolean, not text)",
        ),
        (
            ("scenarios", 0, "method"),
            5,
            "scenarios[0].method = 5: allowed values are ['design', 'random', 'antithetic']",
        ),
        (
            ("k_selection", 0, "methods"),
            ["design", None],
            "k_selection[0].methods[1] = None: allowed values are "
            "['design', 'random', 'antithetic']",
        ),
    ],
    ids=["stan_init", "method", "methods"],
)
def test_a_value_of_the_wrong_type_for_an_enum_gets_one_message(path, value, message):
    c = base()
    c["k_selection"] = [{"name": "k", "scenario": "s", "K_grid": [10, 20]}]
    target = c
    for part in path[:-1]:
        target = target[part]
    target[path[-1]] = value
    msg = refused(c)
    assert msg == f"invalid configuration:\n  - {message}"


def test_nested_values_from_the_command_line_are_read_as_yaml_scalars():
    cli = pytest.importorskip("snakemake.cli")
    given = cli.parse_config(
        [
            "stan={chains: 1, adapt_delta: 0.9, keep_draws: [1, 2]}",
            "design={b_max: null}",
            "convergence={treedepth_fails: true, max_divergences: 3}",
            "scenarios=[{name: s, model: same, omega: {a: 0.9}, x0: 8, T: 4, K: 10, "
            "stan: false, stan_init: 'true'}]",
        ]
    )
    assert given["stan"]["chains"] == "1"  # what Snakemake hands over
    c = cfg.validate(given)
    assert c["stan"]["chains"] == 1 and c["stan"]["adapt_delta"] == 0.9
    assert c["stan"]["keep_draws"] == [1, 2]
    assert c["design"]["b_max"] is None
    assert c["convergence"] == {**c["convergence"], "treedepth_fails": True, "max_divergences": 3}
    sc = c["scenarios"][0]
    assert (sc["omega"], sc["x0"], sc["T"], sc["K"], sc["stan"]) == ({"a": 0.9}, 8, 4, 10, False)
    assert sc["stan_init"] == "true"  # a string key stays a string
    msg = refused({**base(), **cli.parse_config(["stan={chains: 1.0, iter_warmup: many}"])})
    assert "stan.chains = 1.0: must be a whole number written without a decimal point" in msg
    assert "stan.iter_warmup = 'many': must be of type integer" in msg


def test_check_config_files_refuses_duplicate_keys_in_snakemakes_config_files(tmp_path):
    good, bad = tmp_path / "good.yaml", tmp_path / "bad.yaml"
    good.write_text("stan: {chains: 2}\n")
    bad.write_text("stan: {chains: 2}\nscenarios: []\nstan: {chains: 4}\n")
    cfg.check_config_files([good])
    with pytest.raises(RuntimeError) as err:
        cfg.check_config_files([good, bad], error=RuntimeError)
    assert str(err.value) == (
        f"config file {bad}, line 3, column 1: key 'stan' appears twice in one mapping "
        f"(also line 1); YAML would silently keep only the last value: remove one"
    )


@pytest.mark.parametrize("name", [p for p in PROFILES if "/" in p])
def test_subsets_of_design_sets_keep_their_point_symmetry(name):
    """Section IV rows and variants on every m-th design trajectory: m divides K/2, so the
    subset holds both points of every pair s, -s (docs/decisions.md)."""
    for sc in cfg.validate(load(name))["scenarios"]:
        m = sc.get("stan_every", 1)
        assert sc["method"] == "design" and (sc["K"] // 2) % m == 0, (sc["name"], sc["K"], m)


@pytest.mark.parametrize("name", PROFILES)
def test_every_profile_but_the_own_study_asks_for_the_papers_outputs(name):
    """The committed profiles keep the paper's tables and figures; the SV study, a model of
    one's own, asks for none of them (issue 36)."""
    assert cfg.asks_for_paper_outputs(cfg.validate(load(name))) == (name != "stoch_vol.yaml")


def test_a_paper_scenario_or_paper_outputs_asks_for_the_papers_outputs():
    own = {"name": "sv", "model": "stoch_vol", "omega": {"phi": 0.9, "sigma": 0.5}}
    own.update(x0=0, T=5, K=4)
    same = same_a09(name="same_T4")
    assert not cfg.asks_for_paper_outputs(cfg.validate({"scenarios": [dict(own)]}))
    assert not cfg.asks_for_paper_outputs(cfg.validate({"scenarios": [dict(own), dict(same)]}))
    named = {**same, "paper_ref": "same_a09_T4"}
    assert cfg.asks_for_paper_outputs(cfg.validate({"scenarios": [dict(own), named]}))
    chosen = {"scenarios": [dict(own), dict(same)], "paper_outputs": {"figure4": "same_T4"}}
    assert cfg.asks_for_paper_outputs(cfg.validate(chosen))
