"""The error kinds' registry is the one home of a kind: the tensor's arrays are its arrays, each kind's
bounds are the `errors.*` params, the PEM's terms are of registered kinds, and a kind registered here
(a toy: its record and the registry's line, nothing else) flows through the tensor, its checks, the
attack function, the guided search's wrongness and the lockstep codec without a line of those
modules naming it."""

import json
from dataclasses import fields

import numpy as np
import pytest
from test_error_kinds import _truth

from advperc_ros.configs import ERRORS
from advperc_ros.core.pem import TERMS
from advperc_ros.core.perception_errors import (
    KINDS,
    ArraySpec,
    ErrorKind,
    ErrorSpace,
    PerceptionErrors,
    Shown,
    inject,
    registry,
)
from advperc_ros.core.search.guided import wrongness
from advperc_ros.exceptions import MessageError
from advperc_ros.params import SCHEMA
from advperc_ros.ros import lockstep
from advperc_ros.ros import messages as msgs


def test_the_tensors_arrays_are_the_registrys_in_order_the_papers_its_fields():
    everything = PerceptionErrors.none(3, 2, registry.ERROR_KINDS, ghosts=1)
    assert list(everything.arrays()) == [spec.name for kind in KINDS for spec in kind.arrays]
    assert [kind.name for kind in KINDS if kind.paper] == ["position", "yaw", "drop"]
    assert [f.name for f in fields(PerceptionErrors)] == ["dx", "dy", "dyaw", "fn", "extended"]
    assert PerceptionErrors.none(3, 2).dvx is None  # an extended kind's array, while the kind is off
    with pytest.raises(AttributeError, match="no attribute 'dvz'"):
        everything.dvz  # noqa: B018 -- a name no kind registers is no attribute


def test_each_kinds_bounds_are_its_errors_params_and_the_error_spaces_attributes():
    space, bounded = ErrorSpace(), set()
    for kind in KINDS:
        for bound in kind.bounds:
            param = SCHEMA[f"errors.{bound.name}"]
            assert param.description == bound.description and bound.description.startswith(f"{kind.name} kind:")
            assert param.default == getattr(space, bound.name) == bound.default and type(param.default) is param.type
            assert param.check(f"errors.{bound.name}", bound.default) == bound.default  # within its range
            assert ERRORS[bound.name] == f"errors.{bound.name}"  # and the config table maps it
            bounded.add(bound.name)
    assert bounded == {name[len("errors."):] for name in SCHEMA if name.startswith("errors.")} - {"kinds"}
    assert ErrorSpace(max_scale=1.6).max_scale == 1.6 and ErrorSpace(max_scale=1.6).min_scale == space.min_scale
    with pytest.raises(TypeError, match="'max_height', which no error kind declares as a bound"):
        ErrorSpace(max_height=3.0)


def test_a_kinds_arrays_keep_the_floor_its_bounds_allow():
    """The smallest scale the params allow is above 0, as the tensor requires; a latency move draws 1 or more."""
    size, latency = registry.kind_named("size"), registry.kind_named("latency")
    assert all(spec.above == 0.0 for spec in size.arrays) and SCHEMA["errors.min_scale"].positive
    assert latency.arrays[0].at_least == 0.0 and SCHEMA["errors.max_latency"].low == 1


def test_every_pem_term_is_of_a_registered_kind_beyond_the_papers_in_registry_order():
    order = [kind.name for kind in KINDS]
    assert all(not registry.kind_named(term.kind).paper for term in TERMS)
    assert [term.kind for term in TERMS] == sorted((term.kind for term in TERMS), key=order.index)


# ----- a toy kind, registered by the test alone -----
def _show_height(shown: Shown, errors: PerceptionErrors, rows: slice) -> None:
    shown.boxes["height"] = shown.source["height"] * errors.height_scale[rows]


def _height_wrongness(errors: PerceptionErrors, space: ErrorSpace) -> np.ndarray:
    return np.minimum(np.abs(np.log(errors.height_scale)) / np.log(2.0), 1.0)


HEIGHT = ErrorKind(name="height", arrays=(ArraySpec("height_scale", 1.0, above=0.0),), show=_show_height,
                   wrongness=_height_wrongness)


@pytest.fixture
def toy(monkeypatch):
    monkeypatch.setattr(registry, "KINDS", (*registry.KINDS, HEIGHT))  # the registry's one line
    return HEIGHT


def test_a_kind_registered_in_a_test_flows_through_tensor_checks_injection_wrongness_and_codec(toy):
    truth = _truth(6, 3, gaps=False)
    errors = PerceptionErrors.none(6, 3, ("position", "height"))
    assert errors.kinds == ("position", "yaw", "drop", "height") and (errors.height_scale == 1.0).all()
    assert not errors.attacked().any() and errors.used_kinds(6) == ()
    assert (wrongness(errors) == 0.0).all()
    errors.height_scale[2:4, 1] = 1.5
    assert errors.attacked()[2:4, 1].all() and errors.attacked().sum() == 2 and errors.used_kinds(6) == ("height",)
    assert np.allclose(wrongness(errors)[2:4, 1], np.log(1.5) / np.log(2.0)) and wrongness(errors).sum() > 0
    shown = inject(truth, errors)
    assert np.array_equal(shown.height[2:4, 1], truth.height[2:4, 1] * 1.5)
    assert np.array_equal(shown.height[:2], truth.height[:2]) and np.array_equal(shown.x, truth.x)
    assert not errors.without("height").attacked().any()

    arrays = errors.arrays()
    assert list(arrays)[-1] == "height_scale" and PerceptionErrors.from_arrays(arrays).equals(errors)
    with pytest.raises(ValueError, match="field 'height_scale' must be above 0 everywhere"):
        PerceptionErrors.from_arrays({**arrays, "height_scale": np.zeros((6, 3))})
    with pytest.raises(ValueError, match="field 'height_scale' must hold finite numbers"):
        PerceptionErrors.from_arrays({**arrays, "height_scale": np.full((6, 3), np.inf)})

    item = lockstep.RolloutErrors(7, errors, np.arange(3), np.arange(6) * 100, False)
    back = lockstep.parse_errors(lockstep.errors_message(item))
    assert back.errors.equals(errors) and back.errors.height_scale.dtype == float
    data = json.loads(lockstep.errors_message(item).data)
    data["height_scale"] = np.ones((6, 3), dtype=bool).tolist()  # the element type is the kind's dtype's
    with pytest.raises(MessageError, match="field 'height_scale' must be a 6x3 array of finite numbers"):
        lockstep.parse_errors(msgs.string(json.dumps(data)))


def test_without_the_toy_registered_its_array_is_no_part_of_a_tensor():
    with pytest.raises(ValueError, match="field 'height_scale' is no part of an error tensor"):
        PerceptionErrors.from_arrays({**PerceptionErrors.none(2, 2).arrays(), "height_scale": np.ones((2, 2))})
