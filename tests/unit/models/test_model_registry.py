"""Models are found by slug; a broken model module gives one clear message naming the file."""

from __future__ import annotations

import textwrap
from pathlib import Path

import pytest
from ssmobs.config.validation import ConfigError
from ssmobs.models import MODELS, ModelDefinitionError, discover_models, model_files

pytestmark = pytest.mark.unit

GOOD = """
import numpy as np
from ssmobs.models.base import StateSpaceModel


class {cls}(StateSpaceModel):
    slug = "{slug}"
    title = "toy"
    obs_dim = 1
    state_dim = 1
    param_names = ("a",)
    default_prior = {{"a": "restricted"}}
    allowed_priors = {{"a": ("restricted",)}}

    def obs_term(self, omega, x, z):
        return (z[0] - x[0]) ** 2

    def trans_term(self, omega, x_prev, x):
        return (x[0] - omega[0] * x_prev[0]) ** 2

    def simulate(self, omega, x0, eta, eps):
        x = np.cumsum(eta, axis=1) + x0[0]
        return x, x + eps
"""


def write(directory: Path, stem: str, text: str) -> None:
    (directory / f"{stem}.py").write_text(textwrap.dedent(text))


def test_package_models_are_found_by_file_name():
    stems = {p.stem for p in model_files()}
    assert stems == set(MODELS)
    assert {"same", "sep", "sep_d2_p1", "sep_d1_p2", "sep_ranwalk", "sep_mult", "stoch_vol"} <= set(
        MODELS
    )
    for slug, model in MODELS.items():
        assert model.slug == slug


def test_a_new_module_is_registered_without_editing_anything(tmp_path):
    write(tmp_path, "toy", GOOD.format(cls="Toy", slug="toy"))
    write(tmp_path, "_helper", "X = 1\n")  # private modules are not models
    models = discover_models(tmp_path)
    assert list(models) == ["toy"]
    assert models["toy"].n_theta(3) == 1 + 4


def test_missing_attribute_names_file_and_attribute(tmp_path):
    write(tmp_path, "toy", GOOD.format(cls="Toy", slug="toy").replace('    title = "toy"\n', ""))
    with pytest.raises(ModelDefinitionError) as err:
        discover_models(tmp_path)
    msg = str(err.value)
    assert "toy.py" in msg and "['title']" in msg and "missing required class attribute" in msg


def test_missing_method(tmp_path):
    text = GOOD.format(cls="Toy", slug="toy")
    text = text[: text.index("    def simulate")]
    write(tmp_path, "toy", text)
    with pytest.raises(ModelDefinitionError, match=r"missing required method\(s\) \['simulate'\]"):
        discover_models(tmp_path)


def test_slug_used_twice_names_both_files(tmp_path):
    write(tmp_path, "toy", GOOD.format(cls="Toy", slug="toy"))
    write(tmp_path, "toy_copy", GOOD.format(cls="ToyCopy", slug="toy"))  # copied, slug unchanged
    with pytest.raises(ModelDefinitionError) as err:
        discover_models(tmp_path)
    msg = str(err.value)
    assert "slug 'toy' is used twice" in msg
    assert "toy.py (Toy)" in msg and "toy_copy.py (ToyCopy)" in msg


def test_slug_must_equal_file_name(tmp_path):
    write(tmp_path, "toy", GOOD.format(cls="Toy", slug="other"))
    with pytest.raises(ModelDefinitionError, match="slug = 'other' but the file is toy.py"):
        discover_models(tmp_path)


def test_module_without_model_class(tmp_path):
    write(tmp_path, "toy", "X = 1\n")
    with pytest.raises(ModelDefinitionError, match="toy.py: must define exactly one subclass"):
        discover_models(tmp_path)


def test_import_error_names_the_file(tmp_path):
    write(tmp_path, "toy", "import not_a_module_xyz\n")
    with pytest.raises(ModelDefinitionError, match=r"toy.py: import failed: ModuleNotFoundError"):
        discover_models(tmp_path)


@pytest.mark.parametrize(
    "old, new, words",
    [
        ('param_names = ("a",)', 'param_names = ("x0",)', ["param_names ['x0'] are not allowed"]),
        (
            'default_prior = {"a": "restricted"}',
            'default_prior = {"b": "restricted"}',
            ["default_prior must have exactly one entry per parameter ['a']"],
        ),
        (
            'allowed_priors = {"a": ("restricted",)}',
            'allowed_priors = {"a": ("half_line",)}',
            ["default_prior['a'] = 'restricted' is not in allowed_priors['a']"],
        ),
        ("obs_dim = 1", "obs_dim = 0", ["obs_dim = 0 must be an integer >= 1"]),
    ],
)
def test_contract_problems(tmp_path, old, new, words):
    text = GOOD.format(cls="Toy", slug="toy")
    assert old in text
    write(tmp_path, "toy", text.replace(old, new))
    with pytest.raises(ModelDefinitionError) as err:
        discover_models(tmp_path)
    for w in words:
        assert w in str(err.value)


def test_a_broken_module_stops_only_the_lookups_of_its_model(tmp_path, monkeypatch):
    """Found before (issue 46): a model file with a syntax error stopped every config with
    a 29-line traceback, also configs that do not use it.  Now the registry finds the other
    models and a lookup of the broken one gives one line naming its file."""
    import ssmobs.models as models

    write(tmp_path, "toy", GOOD.format(cls="Toy", slug="toy"))
    write(tmp_path, "broken", "def broken(:\n")
    real = models._discover
    monkeypatch.setattr(models, "_discover", lambda directory: real(tmp_path))
    registry = models._Registry()
    assert list(registry) == ["toy"] and registry["toy"].slug == "toy"
    with pytest.raises(ModelDefinitionError) as err:
        registry["broken"]
    msg = str(err.value)
    assert "\n" not in msg and f"{tmp_path / 'broken.py'}: import failed: SyntaxError" in msg
    assert "configs that do not use model 'broken' run" in msg
    with pytest.raises(KeyError):
        registry["unknown"]
    with pytest.raises(ModelDefinitionError, match="broken.py: import failed"):
        discover_models(tmp_path)  # the strict discovery lists every problem


def test_the_preflight_names_a_broken_model_a_config_uses_in_one_line(tmp_path, monkeypatch):
    import ssmobs.config.validation as config_module
    import ssmobs.models as models
    from ssmobs.config.preflight import check_config_file

    write(tmp_path, "broken", "def broken(:\n")
    real = models._discover
    monkeypatch.setattr(
        models, "_discover", lambda d: (real(models.MODELS_DIR)[0], real(tmp_path)[1])
    )
    registry = models._Registry()
    monkeypatch.setattr(config_module, "MODELS", registry)
    scenario = "scenarios:\n  - {name: s, model: %s, omega: {a: 0.9}, x0: 8, T: 4, K: 4}\n"
    good, bad = tmp_path / "good.yaml", tmp_path / "bad.yaml"
    good.write_text(scenario % "same")
    bad.write_text(scenario % "broken")
    check_config_file(good)
    with pytest.raises(ConfigError) as err:
        check_config_file(bad)
    assert str(err.value).startswith(f"config file {bad}: model module {tmp_path / 'broken.py'}")
    assert "\n" not in str(err.value)


def test_default_prior_may_be_an_interval_with_infinite_bounds(tmp_path):
    """A model file may write "flat on the whole line" as its default prior (issue 60)."""
    text = GOOD.format(cls="Toy", slug="toy").replace(
        '{"a": "restricted"}', '{"a": (-float("inf"), float("inf"))}'
    )
    write(tmp_path, "toy", text)
    bounds = discover_models(tmp_path)["toy"].prior_bounds({"a": 0.5})
    assert (bounds.lower[0], bounds.upper[0]) == (-float("inf"), float("inf"))


def test_default_prior_interval_must_be_ordered(tmp_path):
    text = GOOD.format(cls="Toy", slug="toy").replace('{"a": "restricted"}', '{"a": (1.0, 0.0)}')
    write(tmp_path, "toy", text)
    with pytest.raises(ModelDefinitionError, match=r"default_prior\['a'\].*lower < upper"):
        discover_models(tmp_path)
