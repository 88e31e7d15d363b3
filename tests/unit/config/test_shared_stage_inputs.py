"""The two shared stages' inputs objects (issue 62): the design sets, keyed once per config
(:class:`~ssmobs.config.stage_inputs.DesignSetsInputs`), and a model's compiled program
(:class:`~ssmobs.config.stage_inputs.ProgramInputs`).  Their keys hold exactly the payloads
they held before these objects, so no cache moved; a rule's params are looked up by the key
they are made of; every setting of the ``design`` block is a field."""

from __future__ import annotations

import copy
import dataclasses

import pytest
import yaml
from ssmobs import kernels
from ssmobs.cache_keys import CacheKeys
from ssmobs.config import validation as cfg
from ssmobs.config.stage_inputs import DesignSetsInputs, ProgramInputs
from ssmobs.config.validation import validate
from ssmobs.stage_table import PACKAGE_DIR, STAGES

pytestmark = pytest.mark.unit

REPO = PACKAGE_DIR.parents[1]


def smoke(gradients: str = "autodiff", b_max: float | None = None) -> dict:
    """The smoke profile, validated, on NUTS path ``gradients`` with ``design.b_max``."""
    conf = yaml.safe_load((REPO / "config" / "smoke.yaml").read_text())
    conf["stan"]["gradients"] = gradients
    conf["design"] = {"b_max": b_max}
    return validate(conf)


def test_every_setting_of_the_design_block_is_a_field_of_the_design_inputs():
    """A setting added to the ``design`` block and not to the inputs would be read by
    nobody, or read around the key: the two name the same settings."""
    block = cfg.load_schema()["properties"]["design"]["properties"]
    assert {f.name for f in dataclasses.fields(DesignSetsInputs)} == set(block)


@pytest.mark.parametrize("b_max", [None, 2, 2.5])
def test_the_design_key_holds_the_design_block_as_before(b_max):
    """The payload of the design sets' key is the one it held before the inputs object: the
    ``design`` block as the config gives it (a ``2`` kept an int), the code and the
    kernels; the rule's param is that block, as the inputs give it."""
    conf = smoke(b_max=b_max)
    k = CacheKeys(conf, "native")
    inputs = k.design_inputs
    assert isinstance(inputs, DesignSetsInputs) and inputs.design_config == conf["design"]
    key = k.design
    payload = k.describe()[f"design:shared:{key}"]
    assert payload == {
        "design": conf["design"],
        "code": k.code("design"),
        "kernels": kernels.SETTINGS_ID,
    }
    assert type(payload["design"]["b_max"]) is type(b_max)
    assert k.lookup("design", "shared", key) == {"inputs": inputs}


def test_another_design_block_moves_the_design_key():
    assert CacheKeys(smoke(), "native").design != CacheKeys(smoke(b_max=2.5), "native").design


def _program_payload_before(k: CacheKeys, model: str) -> dict:
    """What the program's key held before its inputs object (CacheKeys.program then)."""
    mode = k.config["stan"]["gradients"]
    own = (k.repo / "stan" / f"{model}.stan").is_file()
    analytic = {} if mode == "autodiff" or not own else {"gradients": mode}
    return {
        "backend": k.backend,
        "stan": k.stan_program(model),
        "code": k.code("program"),
        **analytic,
        **({"model_code": k.model_code(model)} if analytic else {}),
        "kernels": kernels.SETTINGS_ID,
    }


@pytest.mark.parametrize("gradients", ["autodiff", "analytic"])
@pytest.mark.parametrize("own", [True, False])
def test_the_program_key_holds_what_it_held_before(tmp_path, gradients, own):
    """A hand-written program (stan/same.stan) and one generated for a model without one,
    on either gradient path: the key's payload is the one it held before the inputs object;
    the rule's params, looked up by the key, are the inputs' backend and gradient path."""
    repo = REPO
    if not own:
        (tmp_path / "stan").mkdir()  # no stan/same.stan: its program is generated
        repo = tmp_path
    k = CacheKeys(smoke(gradients), "native stanc3 test", repo=repo, backend_name="native")
    inputs = k.program_inputs("same")
    assert isinstance(inputs, ProgramInputs) and inputs.generated is not own
    assert (inputs.model, inputs.backend, inputs.stan_version) == (
        "same",
        "native",
        "native stanc3 test",
    )
    # a generated program is analytic whatever the key and keyed by what it is made of
    assert inputs.gradients == (gradients if own else "autodiff")
    key = k.program("same")
    assert k.describe()[f"program:same:{key}"] == _program_payload_before(k, "same")
    assert k.lookup("program", "same", key) == {"inputs": inputs}


def test_another_stan_or_backend_moves_the_program_or_its_marker():
    conf = smoke()
    a = CacheKeys(conf, "native stanc3 v1", backend_name="native")
    b = CacheKeys(conf, "native stanc3 v2", backend_name="native")
    c = CacheKeys(conf, "native stanc3 v1", backend_name="cmdstanpy")
    assert a.program("same") != b.program("same")
    assert a.program("same") == c.program("same")  # the backend's name is the path's
    name = next(n for n, sc in a.scenarios.items() if sc["model"] == "same")
    assert a.program_marker(name) != c.program_marker(name)
    edited = copy.deepcopy(conf)
    edited["stan"]["gradients"] = "analytic"
    assert CacheKeys(edited, "native stanc3 v1").program("same") != a.program("same")


def test_the_shared_stages_are_registered_with_their_builders():
    k = CacheKeys(smoke(), "native")
    assert STAGES["design"].of == "config" and STAGES["program"].of == "model"
    assert STAGES["design"].inputs is not None and STAGES["program"].inputs is not None
    assert STAGES["design"].inputs(k.config) == k.design_inputs
    built = STAGES["program"].inputs(
        "same", k.config, backend="native", stan_version="native", program="generated-0"
    )
    assert built.generated and built.gradients == "autodiff"
