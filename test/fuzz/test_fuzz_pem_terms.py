"""Fuzzing the loader on the calibrated default, whose every term is on: a field of the new terms
given any JSON value or number loads into a model that samples and scores a scene, or fails with one
PEMError line naming the file and the field."""

import dataclasses
import json
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from pem_scenes import moving_scene
from test_fuzz_pem import json_values, numbers, one_line_naming

from advperc_ros.core.pem import PEM, default_pem
from advperc_ros.core.perception_errors import ERROR_KINDS
from advperc_ros.exceptions import PEMError

FUZZ = settings(max_examples=100, deadline=2000, suppress_health_check=[HealthCheck.too_slow])
# finite but absurd values (degrees of freedom of 1e-300 draw infinite errors, as the paper's terms' do)
pytestmark = [pytest.mark.filterwarnings(f"ignore:{what}:RuntimeWarning") for what in ("overflow", "divide", "invalid")]
VALID = dataclasses.asdict(default_pem(ERROR_KINDS))
NEW_TERMS = sorted(set(VALID) - {"detection", "position_loc", "radial_log_scale", "tangential_log_scale",
                                 "position_rho", "position_nu", "yaw_log_scale", "yaw_nu", "source"})
TRUTH, EGO = moving_scene(np.random.default_rng(0), frames=12)


@FUZZ
@given(field=st.sampled_from(NEW_TERMS), value=json_values | numbers, remove=st.booleans())
def test_a_new_term_of_any_value_loads_usable_or_fails_naming_it(field, value, remove, tmp_path_factory):
    document = {k: v for k, v in VALID.items() if not (remove and k == field)}
    if not remove:
        document[field] = value
    path = tmp_path_factory.mktemp("pem") / "model.json"
    path.write_text(json.dumps(document))
    try:
        model = PEM.load(path)
    except PEMError as exc:
        one_line_naming(exc, str(path), repr(field))
        return
    errors = model.sample(TRUTH, EGO, np.random.default_rng(1))
    assert all(type(getattr(model, f.name)) is (str if f.name == "source" else type(VALID[f.name]) if not
               isinstance(VALID[f.name], list) else tuple) for f in dataclasses.fields(PEM))
    score = model.score(TRUTH, errors, EGO, TRUTH.valid)
    assert math.isnan(score) or score < math.inf
