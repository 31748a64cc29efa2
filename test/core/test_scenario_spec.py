"""Scenario descriptions: junction connectors join lanes smoothly; bad descriptions name the field."""

import numpy as np
import pytest

from advperc_ros.core.geometry import Polyline
from advperc_ros.core.scenario_spec import build_scenario, connector
from advperc_ros.exceptions import ScenarioError


def test_connector_joins_end_to_start_with_matching_headings():
    stem = Polyline(np.array([[1.75, -60.0], [1.75, -7.0]]))
    exit_lane = Polyline(np.array([[-7.0, 1.75], [-200.0, 1.75]]))
    turn = connector(stem, exit_lane, points=200)
    np.testing.assert_allclose(turn.points[0], stem.points[-1])
    np.testing.assert_allclose(turn.points[-1], exit_lane.points[0])
    assert turn.heading(0.0) == pytest.approx(np.pi / 2, abs=0.02)
    assert abs(abs(turn.heading(turn.length - 1e-6)) - np.pi) < 0.02
    # a quarter turn of radius ~8.75 m: arc length close to 2 pi r / 4
    assert turn.length == pytest.approx(2 * np.pi * 8.75 / 4, rel=0.06)
    step_turn = np.abs(np.diff(np.unwrap(turn.heading(turn.stations[:-1]))))
    assert step_turn.max() < 0.05  # no kink anywhere


def test_connector_must_name_earlier_lanes():
    spec = {"name": "bad", "dt": 0.1, "duration": 1.0,
            "lanes": [{"id": "a", "centerline": [[0, 0], [10, 0]]}, {"id": "turn", "connect": ["a", "b"]}],
            "ego": {"route": ["a"], "start_s": 1.0}}
    with pytest.raises(ScenarioError, match=r"lanes\[1\]\.connect"):
        build_scenario(spec, "spec.yaml")


def test_missing_field_is_named():
    with pytest.raises(ScenarioError, match=r"spec.yaml: field 'ego' is missing"):
        build_scenario({"name": "x", "dt": 0.1, "duration": 1.0, "lanes": []}, "spec.yaml")
