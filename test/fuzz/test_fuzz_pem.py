"""Fuzzing the perception error model's loader: a model file of any content (another schema, lists
of the wrong length, NaN, garbage bytes) loads into a usable model or fails with one PEMError
line naming the file and, where there is one, the field; never a TypeError from the dataclass or
a shape error in the middle of a search."""

import dataclasses
import json
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from advperc_ros.core.pem import NUM_FEATURES, PEM, default_pem
from advperc_ros.exceptions import PEMError

FUZZ = settings(max_examples=200, deadline=2000, suppress_health_check=[HealthCheck.too_slow])  # deadline: hang guard
pytestmark = pytest.mark.filterwarnings("ignore:overflow:RuntimeWarning")  # finite but absurd weights
VALID = dataclasses.asdict(default_pem())
FIELDS = sorted(VALID)

json_values = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=6),
    lambda inner: st.lists(inner, max_size=6) | st.dictionaries(st.text(max_size=6), inner, max_size=3),
    max_leaves=12,
)
numbers = st.floats() | st.integers(-10**400, 10**400)  # NaN, inf, and ints no float can hold


def one_line_naming(exc: Exception, *names: str) -> None:
    text = str(exc)
    assert "\n" not in text and "\r" not in text, text
    for name in names:
        assert name in text, (name, text)


def usable(model: PEM) -> None:
    """What a loaded model promises: every number finite, every weight vector as long as phi, a
    correlation in (-1, 1) and positive degrees of freedom, so sampling and scoring work."""
    for field in dataclasses.fields(PEM):
        value = getattr(model, field.name)
        if field.name == "source":
            assert isinstance(value, str)
        elif isinstance(value, tuple):
            assert len(value) == (2 if field.name == "position_loc" else NUM_FEATURES)
            assert all(type(v) is float and math.isfinite(v) for v in value)
        else:
            assert type(value) is float and math.isfinite(value)
    assert -1.0 < model.position_rho < 1.0 and model.position_nu > 0.0 and model.yaw_nu > 0.0
    phi = np.array([[1.0, 0.2, 0.04, 0.0, 0.8]])
    detected, rt, dyaw = model.sample_features(phi, np.random.default_rng(0))
    assert detected.shape == (1,) and rt.shape == (1, 2) and dyaw.shape == (1,)


@st.composite
def model_documents(draw) -> tuple[dict | object, str | None]:
    """(a JSON document, the field it breaks or None): the valid model with one field removed,
    replaced by any JSON value, resized or given a NaN; an unknown field added; or any JSON."""
    kind = draw(st.sampled_from(["replace", "remove", "resize", "number", "unknown", "document"]))
    if kind == "document":
        return draw(json_values), None
    document = dict(VALID)
    field = draw(st.sampled_from(FIELDS))
    if kind == "remove":
        del document[field]
    elif kind == "replace":
        document[field] = draw(json_values)
    elif kind == "resize" and isinstance(document[field], (list, tuple)):
        document[field] = list(document[field]) + [0.0] * draw(st.integers(1, 3)) if draw(st.booleans()) else \
            list(document[field])[: draw(st.integers(0, len(document[field]) - 1))]
    elif kind == "number" and field != "source":
        value = draw(numbers)
        if isinstance(document[field], (list, tuple)):
            at = draw(st.integers(0, len(document[field]) - 1))
            value = [*document[field][:at], value, *document[field][at + 1:]]
        document[field] = value
    elif kind == "unknown":
        field = draw(st.text(min_size=1, max_size=8).filter(lambda name: name not in VALID))
        document[field] = draw(json_values)
    return document, field


@FUZZ
@given(case=model_documents())
def test_any_model_document_loads_usable_or_fails_naming_the_field(case, tmp_path_factory):
    document, field = case
    path = tmp_path_factory.mktemp("pem") / "model.json"
    path.write_text(json.dumps(document))
    try:
        model = PEM.load(path)
    except PEMError as exc:
        one_line_naming(exc, str(path))
        if field is not None and str(exc).startswith(f"{path}: field"):
            assert repr(field) in str(exc)  # names as repr: a field may hold any character
    else:
        usable(model)


@FUZZ
@given(data=st.binary(max_size=200) | st.text(max_size=60).map(str.encode))
def test_garbage_files_fail_with_one_line_naming_the_file(data, tmp_path_factory):
    path = tmp_path_factory.mktemp("pem") / "garbage.json"
    path.write_bytes(data)
    try:
        usable(PEM.load(path))
    except PEMError as exc:
        one_line_naming(exc, str(path))


@pytest.mark.parametrize("change, words", [
    ({"detection": [4.6, -2.4, 0.0]}, ["'detection'", "5 numbers"]),
    ({"position_rho": 1.0}, ["'position_rho'", "(-1.0, 1.0)"]),
    ({"yaw_nu": -4.0}, ["'yaw_nu'"]),
    ({"radial_log_scale": [float("nan"), 0.98, 0.0, 0.4, 0.0]}, ["'radial_log_scale'", "in (-30, 30)"]),
    ({"position_nu": True}, ["'position_nu'", "a number"]),
    ({"colour": "red"}, ["'colour'", "unknown"]),
])
def test_wrong_fields_are_named(change, words, tmp_path):
    path = tmp_path / "model.json"
    path.write_text(json.dumps({**VALID, **change}))
    with pytest.raises(PEMError) as caught:
        PEM.load(path)
    one_line_naming(caught.value, str(path), *words)


def test_missing_field_and_missing_file_are_named(tmp_path):
    path = tmp_path / "model.json"
    path.write_text(json.dumps({k: v for k, v in VALID.items() if k != "yaw_nu"}))
    with pytest.raises(PEMError, match="'yaw_nu'"):
        PEM.load(path)
    with pytest.raises(PEMError) as caught:
        PEM.load(tmp_path / "absent.json")
    one_line_naming(caught.value, "absent.json")


def test_a_log_scale_beyond_its_bound_is_refused_on_loading(tmp_path):
    """A scale of e^300 made every density 0 and `advperc score` print "pem_ll": -Infinity, which is not JSON."""
    path = tmp_path / "model.json"
    default_pem().save(path)
    model = json.loads(path.read_text())
    model["radial_log_scale"] = [300.0, 0.0, 0.0, 0.0, 0.0]
    path.write_text(json.dumps(model))
    with pytest.raises(PEMError, match=r"field 'radial_log_scale' must be a list of 5 numbers in \(-30, 30\)"):
        PEM.load(path)
