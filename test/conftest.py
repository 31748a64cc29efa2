"""Shared fixtures: the repository's bundled scenarios and bags."""

from pathlib import Path

import pytest

from advperc_ros.ros.bag import read_scenario

REPO = Path(__file__).resolve().parent.parent
IDM_SCENARIOS = ("idm_lane_following", "idm_overtake_follow")


@pytest.fixture(scope="session")
def repo() -> Path:
    return REPO


@pytest.fixture(scope="session", params=IDM_SCENARIOS)
def bundled(request):
    """(name, scenario read from its committed bag, params file path) per bundled scenario."""
    name = request.param
    return name, read_scenario(REPO / "bags" / name), REPO / "config" / f"{name}.yaml"
