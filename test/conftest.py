"""Shared fixtures: the repository's bundled scenarios and bags."""

from pathlib import Path

import pytest

from advperc_ros.ros.bag import read_scenario

REPO = Path(__file__).resolve().parent.parent
IDM_SCENARIOS = ("idm_lane_following", "idm_overtake_follow")
# ObP rollouts take seconds each: their 100-sample checks run through `advperc check-typical`
ALL_SCENARIOS = (*IDM_SCENARIOS, "obp_overtake", "obp_left_turn", "obp_right_turn")


def _bundled(name: str):
    return name, read_scenario(REPO / "bags" / name), REPO / "config" / f"{name}.yaml"


@pytest.fixture(scope="session")
def repo() -> Path:
    return REPO


@pytest.fixture(scope="session", params=ALL_SCENARIOS)
def bundled(request):
    """(name, scenario read from its committed bag, params file path) per bundled scenario."""
    return _bundled(request.param)


@pytest.fixture(scope="session", params=IDM_SCENARIOS)
def idm_bundled(request):
    """The bundled scenarios whose 100-rollout checks are cheap enough for the test suite."""
    return _bundled(request.param)
