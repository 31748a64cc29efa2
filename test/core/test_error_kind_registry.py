"""The error kinds' registry is the one home of a kind: the tensor's fields are its arrays, each kind's
bounds are the `errors.*` params, the PEM's terms are of registered kinds, and a kind registered here
(a toy) flows through the tensor, its checks, the attack function, the guided search's wrongness and
the lockstep codec without a line of those modules naming it."""

import json
from dataclasses import dataclass, fields

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


def test_the_tensors_fields_are_the_registrys_arrays_in_order():
    assert [f.name for f in fields(PerceptionErrors)] == [spec.name for kind in KINDS for spec in kind.arrays]
    assert [kind.name for kind in KINDS if kind.paper] == ["position", "yaw", "drop"]
    assert [f.name for f in fields(PerceptionErrors) if f.default is not None] == ["dx", "dy", "dyaw", "fn"]


def test_each_kinds_bounds_are_its_errors_params_with_the_error_spaces_defaults():
    space, bounded = ErrorSpace(), set()
    for kind in KINDS:
        for bound in kind.bounds:
            param = SCHEMA[f"errors.{bound}"]
            assert param.description.startswith(f"{kind.name} kind:"), (kind.name, bound)
            assert param.default == getattr(space, bound) and type(param.default) is param.type
            assert param.check(f"errors.{bound}", getattr(space, bound)) == getattr(space, bound)  # within its range
            assert ERRORS[bound] == f"errors.{bound}"  # and the config table maps it
            bounded.add(bound)
    assert bounded == {name[len("errors."):] for name in SCHEMA if name.startswith("errors.")} - {"kinds"}
    assert bounded == {f.name for f in fields(ErrorSpace)} - {"kinds"}


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
@dataclass(frozen=True)
class ToyErrors(PerceptionErrors):
    """The tensor with the toy kind's array: the one line a new kind adds to the tensor."""

    height_scale: np.ndarray | None = None


def _show_height(shown: Shown, errors: ToyErrors, rows: slice) -> None:
    shown.boxes["height"] = shown.source["height"] * errors.height_scale[rows]


def _height_wrongness(errors: ToyErrors, space: ErrorSpace) -> np.ndarray:
    return np.minimum(np.abs(np.log(errors.height_scale)) / np.log(2.0), 1.0)


HEIGHT = ErrorKind(name="height", arrays=(ArraySpec("height_scale", 1.0, above=0.0),), show=_show_height,
                   wrongness=_height_wrongness)


@pytest.fixture
def toy(monkeypatch):
    monkeypatch.setattr(registry, "KINDS", (*registry.KINDS, HEIGHT))
    monkeypatch.setattr(lockstep, "PerceptionErrors", ToyErrors)
    return HEIGHT


def test_a_kind_registered_in_a_test_flows_through_tensor_checks_injection_wrongness_and_codec(toy):
    truth = _truth(6, 3, gaps=False)
    errors = ToyErrors.none(6, 3, ("position", "height"))
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
    assert list(arrays)[-1] == "height_scale" and ToyErrors.from_arrays(arrays).equals(errors)
    with pytest.raises(ValueError, match="field 'height_scale' must be above 0 everywhere"):
        ToyErrors.from_arrays({**arrays, "height_scale": np.zeros((6, 3))})
    with pytest.raises(ValueError, match="field 'height_scale' must hold finite numbers"):
        ToyErrors.from_arrays({**arrays, "height_scale": np.full((6, 3), np.inf)})

    item = lockstep.RolloutErrors(7, errors, np.arange(3), np.arange(6) * 100, False)
    back = lockstep.parse_errors(lockstep.errors_message(item))
    assert isinstance(back.errors, ToyErrors) and back.errors.equals(errors) and back.errors.height_scale.dtype == float
    data = json.loads(lockstep.errors_message(item).data)
    data["height_scale"] = np.ones((6, 3), dtype=bool).tolist()  # the element type is the kind's dtype's
    with pytest.raises(MessageError, match="field 'height_scale' must be a 6x3 array of finite numbers"):
        lockstep.parse_errors(msgs.string(json.dumps(data)))


def test_without_the_toy_registered_its_array_is_no_part_of_a_tensor():
    with pytest.raises(ValueError, match="field 'height_scale' is no part of an error tensor"):
        PerceptionErrors.from_arrays({**PerceptionErrors.none(2, 2).arrays(), "height_scale": np.ones((2, 2))})
