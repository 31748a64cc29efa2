"""Fuzzing the params loader: a params file of any content (values of every YAML kind where a
parameter is declared, unknown and missing names, odd planner_params, damaged bytes) gives either
params that keep every promise of the schema or one ParamsError line naming the file; never a
TypeError, a traceback from a later stage, or a hang."""

import math

import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from mutations import damaged

from advperc_ros.exceptions import ParamsError
from advperc_ros.exits import EXIT_INPUT, expected_failure
from advperc_ros.params import NODE, PLANNER_PARAMS, SCHEMA, load_params, nest

FUZZ = settings(max_examples=150, deadline=5000, suppress_health_check=[HealthCheck.too_slow])  # deadline: hang guard
NAMES = sorted(SCHEMA)

scalars = (st.none() | st.booleans() | st.integers(-2**70, 2**70) | st.floats() | st.text(max_size=8)
           | st.sampled_from([math.nan, math.inf, -math.inf, 0.0, -0.0, 0, -1]))
yaml_values = scalars | st.lists(scalars, max_size=3) | st.dictionaries(st.text(max_size=6), scalars, max_size=3)


def one_line_naming(exc: ParamsError, path) -> None:
    """What the user sees of it (`advperc` and every node print errors through `expected_failure`):
    one line naming the file, exit code 2."""
    line, code = expected_failure(exc)
    assert code == EXIT_INPUT and "\n" not in line and "\r" not in line and str(path) in line, line


def keeps_the_schema(params) -> None:
    """What a loaded params object promises, checked without the loader's own rule."""
    for name, param in SCHEMA.items():
        value = params.get(name)
        if value is None:
            assert param.default is None, name
            continue
        assert type(value) is param.type, (name, value)
        if param.type is float:
            assert math.isfinite(value), (name, value)
        if param.choices:
            assert value in param.choices, (name, value)
        if param.positive:
            assert value > 0, (name, value)
        if param.low is not None:
            assert value >= param.low, (name, value)
        if param.high is not None:
            assert value <= param.high, (name, value)
    for key, value in params.planner_params.items():
        assert isinstance(key, str) and isinstance(value, (bool, int, float, str)), (key, value)
        assert not isinstance(value, float) or math.isfinite(value), (key, value)


@pytest.fixture(scope="module")
def bag(repo) -> str:
    return str(repo / "bags" / "idm_lane_following")


def load(folder, flat: dict):
    """load_params of a file holding `flat`; None when no YAML file can say it (a name both a value
    and a parent)."""
    path = folder / "p.yaml"
    try:
        path.write_text(yaml.safe_dump({NODE: {"ros__parameters": nest(flat)}}))
    except (ValueError, TypeError):
        return None
    try:
        params = load_params(path)
    except ParamsError as exc:
        one_line_naming(exc, path)
    else:
        keeps_the_schema(params)


def base(bag: str) -> dict:
    return {"bag": bag, "planner": "idm", "objective": "nds_t", "seed": 0}


@FUZZ
@given(name=st.sampled_from(NAMES), value=yaml_values)
def test_any_value_of_a_parameter_loads_into_valid_params_or_one_line(tmp_path_factory, bag, name, value):
    load(tmp_path_factory.mktemp("fuzz"), {**base(bag), name: value})


@FUZZ
@given(changes=st.dictionaries(st.sampled_from(NAMES) | st.text(min_size=1, max_size=12), yaml_values, max_size=4),
       dropped=st.sets(st.sampled_from(NAMES), max_size=3),
       planner_params=st.none() | yaml_values)
def test_any_names_load_into_valid_params_or_one_line(tmp_path_factory, bag, changes, dropped, planner_params):
    flat = {**base(bag), **changes}
    for name in dropped:
        flat.pop(name, None)
    if planner_params is not None:
        flat[PLANNER_PARAMS] = planner_params
    load(tmp_path_factory.mktemp("fuzz"), flat)


@FUZZ
@given(data=st.data())
def test_damaged_params_files_load_or_fail_in_one_line(tmp_path_factory, repo, bag, data):
    text = (repo / "config" / "idm_lane_following.yaml").read_text().replace("bags/idm_lane_following", bag)
    path = tmp_path_factory.mktemp("fuzz") / "p.yaml"
    path.write_bytes(data.draw(damaged(text.encode(), 4, arbitrary=True)))
    try:
        keeps_the_schema(load_params(path))
    except ParamsError as exc:
        one_line_naming(exc, path)
