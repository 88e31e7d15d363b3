"""Numbers written as text (issue 61 item 1): a quoted number of a config file and every
nested value of Snakemake's ``--config`` reach the config check as strings; each is read
as YAML 1.2 writes numbers, or refused in one line naming key, value and allowed form.

Before, such a string was re-read as a YAML 1.1 scalar: ``K: '010'`` planned K = 8,
``T: "4:00"`` T = 240, ``--config 'figure2={K: 010}'`` K = 8."""

from __future__ import annotations

import copy

import pytest
from factories import same_a09
from ssmobs.config import preflight
from ssmobs.config import validation as cfg
from ssmobs.config.numbers import number_text_problem, numbers_from_text
from ssmobs.config.schema import plain_number

pytestmark = pytest.mark.unit

#: (text, what the check makes of it where an integer is wanted: the int, or the words of
#: its refusal)
INTEGER_FORMS = [
    ("10", 10),
    ("+3", 3),
    ("12", 12),
    ("010", "a number with a leading zero, which YAML 1.1 reads as 8 and YAML 1.2 as 10"),
    ("4:00", "a base-60 (sexagesimal) number, which YAML 1.1 reads as 240 and YAML 1.2 as no"),
    ("1_0", "digits with underscores, which YAML 1.1 reads as 10 and YAML 1.2 as no number"),
    ("0x8", "a hexadecimal number (8 in YAML 1.1 and 1.2), not a form a config takes"),
    ("0o7", "an octal or binary number, which YAML 1.1 reads as text and YAML 1.2 as 7"),
    ("0b11", "an octal or binary number, which YAML 1.1 reads as 3 and YAML 1.2 as no number"),
]
ALLOWED = "allowed: a number in plain decimal digits (e.g. 10, 0.5, 1.0e+3)"
SCENARIO = "scenarios:\n  - {name: s, model: same, omega: {a: 0.9}, x0: 8, T: 4, K: %s}\n"


def checked(config: dict) -> dict:
    return cfg.validate(copy.deepcopy(config))


def refusal(config: dict) -> str:
    with pytest.raises(cfg.ConfigError) as err:
        cfg.validate(copy.deepcopy(config))
    return str(err.value)


@pytest.mark.parametrize(("text", "read"), INTEGER_FORMS, ids=[t for t, _ in INTEGER_FORMS])
def test_a_quoted_number_in_a_config_file_is_read_as_yaml_12_or_refused(tmp_path, text, read):
    for quote in ("'", '"'):
        path = tmp_path / "c.yaml"
        path.write_text(SCENARIO % f"{quote}{text}{quote}")
        if isinstance(read, int):
            assert preflight.check_config_file(path)["scenarios"][0]["K"] == read
            continue
        with pytest.raises(cfg.ConfigError) as err:
            preflight.check_config_file(path)
        lines = str(err.value).splitlines()
        assert lines[0] == f"config file {path}: invalid configuration:"
        assert lines[1].startswith(f"  - scenarios[0].K = '{text}': {read}")
        assert lines[1].endswith(ALLOWED) and len(lines) == 2


@pytest.mark.parametrize(("text", "read"), INTEGER_FORMS, ids=[t for t, _ in INTEGER_FORMS])
def test_the_same_number_unquoted_in_a_file_is_read_alike_or_refused(tmp_path, text, read):
    """Unquoted, the file reader refuses the forms YAML 1.1 and 1.2 read differently
    (with line and column); the plain forms give the same value as quoted."""
    path = tmp_path / "c.yaml"
    path.write_text(SCENARIO % text)
    if isinstance(read, int):
        assert preflight.check_config_file(path)["scenarios"][0]["K"] == read
        return
    with pytest.raises(cfg.ConfigError) as err:
        preflight.check_config_file(path)
    assert f"key 'scenarios[0].K': {text} " in str(err.value)
    assert "\n" not in str(err.value)


@pytest.mark.parametrize(("text", "read"), INTEGER_FORMS, ids=[t for t, _ in INTEGER_FORMS])
def test_a_number_from_snakemakes_command_line_is_read_as_yaml_12_or_refused(text, read):
    """``--config 'figure2={a: 0.9, x0: 8, K: 010, seed: 0}'``: Snakemake's own parser
    hands the nested values over as strings, quoted or not; the check reads them."""
    cli = pytest.importorskip("snakemake.cli")
    for written in (text, f"'{text}'", f'"{text}"'):
        given = cli.parse_config([f"figure2={{a: 0.9, x0: 8, K: {written}, seed: 0}}"])
        assert given["figure2"]["K"] == text  # what Snakemake hands over
        config = {"scenarios": [same_a09()], **given}
        if isinstance(read, int):
            assert checked(config)["figure2"]["K"] == read
        else:
            msg = refusal(config)
            assert f"figure2.K = '{text}': " in msg and read in msg and msg.endswith(ALLOWED)


@pytest.mark.parametrize(
    ("text", "value"),
    [("0.95", 0.95), (".5", 0.5), ("9.5e-1", 0.95), ("9e-1", 0.9), ("+0.5", 0.5), ("1.", 1.0)],
)
def test_decimal_fractions_and_exponents_are_read_as_yaml_12_writes_them(text, value):
    """``9e-1`` is a number in YAML 1.2 (text in YAML 1.1, which the schema then refused)."""
    config = {"scenarios": [same_a09()], "stan": {"init_radius": text}}
    assert checked(config)["stan"]["init_radius"] == value
    assert plain_number(text) == value


def test_exponent_for_an_integer_key_is_refused_as_a_decimal_number():
    msg = refusal({"scenarios": [same_a09(K="1e3")]})
    assert "scenarios[0].K = 1000.0: must be a whole number written without a decimal point" in msg


@pytest.mark.parametrize("key", ["T", "seed", "joint_map_n_starts", "stan_every"])
def test_every_integer_key_of_a_scenario_refuses_a_leading_zero(key):
    msg = refusal({"scenarios": [same_a09(**{key: "011"})]})
    read = "which YAML 1.1 reads as 9 and YAML 1.2 as 11"
    assert f"scenarios[0].{key} = '011': a number with a leading zero, {read}" in msg


def test_a_time_of_day_for_the_horizon_is_refused_not_planned_as_240():
    msg = refusal({"scenarios": [same_a09(T="4:00")]})
    assert "scenarios[0].T = '4:00': a base-60 (sexagesimal) number" in msg and "240" in msg


def test_numbers_in_lists_and_map_bases_are_read_by_their_place():
    """K_grid's items, paper_points' [value, T] pairs and a map's base (a scenario entry)."""
    config = {
        "scenarios": [same_a09()],
        "k_selection": [{"name": "k", "scenario": "s", "K_grid": ["10", "20"]}],
        "observability_maps": [
            {
                "name": "m",
                "base": {"model": "same", "omega": {"a": "0.9"}, "x0": "8", "seed": "3"},
                "vary": "a",
                "values": ["0.5", "0.9"],
                "T": ["4"],
                "K": "4",
                "paper_points": [["0.9", "4"]],
            }
        ],
    }
    c = checked(config)
    assert c["k_selection"][0]["K_grid"] == [10, 20]
    entry = c["observability_maps"][0]
    assert entry["base"]["omega"] == {"a": 0.9} and entry["base"]["seed"] == 3
    assert (entry["values"], entry["T"], entry["K"]) == ([0.5, 0.9], [4], 4)
    assert entry["paper_points"] == [[0.9, 4]]
    config["observability_maps"][0]["base"]["seed"] = "03"
    assert "observability_maps[0].base.seed = '03': a number with a leading zero" in refusal(config)
    config["observability_maps"][0]["base"]["seed"] = "3"
    config["k_selection"][0]["K_grid"] = ["10", "020"]
    assert "k_selection[0].K_grid[1] = '020': a number with a leading zero" in refusal(config)


def test_text_keys_keep_their_text_and_booleans_still_read():
    """A key that takes text keeps '010'; booleans and null from the command line are read."""
    config = {
        "scenarios": [same_a09(name="010", stan="false", stan_batch_size="null")],
        "outputs_dir": "paper_figures/010",
    }
    c = checked(config)
    sc = c["scenarios"][0]
    assert (sc["name"], sc["stan"], sc["stan_batch_size"]) == ("010", False, None)
    assert c["outputs_dir"] == "paper_figures/010"


def test_problem_words_name_both_readings():
    assert number_text_problem("10") == "" and number_text_problem("many") == ""
    assert "YAML 1.1 reads as 40 and YAML 1.2 as 50" in number_text_problem("050")
    problems: list[str] = []
    value = numbers_from_text("050", {"type": "integer"}, problems, ("limits", "jobs"))
    assert value == "050" and problems[0].startswith("limits.jobs = '050': ")


def test_a_smoke_overlay_reads_quoted_sizes_as_the_check_does(tmp_path):
    """``make smoke``: a quoted K is cut to the smoke size as a number ('5000' -> 4), a
    refused form is refused there too (it was read by Python's int(), '010' -> 10)."""
    from ssmobs.config.smoke import SMOKE_K, write_overlay

    source, out = tmp_path / "study.yaml", tmp_path / "overlay.yaml"
    source.write_text(SCENARIO % "'5000'")
    assert write_overlay(source, out)["scenarios"][0]["K"] == SMOKE_K
    source.write_text(SCENARIO % "'010'")
    with pytest.raises(cfg.ConfigError) as err:
        write_overlay(source, tmp_path / "other.yaml")
    assert str(err.value).startswith(f"config file {source}: scenarios[0].K = '010': a number")
    source.write_text(SCENARIO % "12.5")
    with pytest.raises(cfg.ConfigError, match=r"scenarios\[0\]\.K = 12.5: must be of type integer"):
        write_overlay(source, tmp_path / "other.yaml")
