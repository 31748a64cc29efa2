"""Shared fixtures: the repository's bundled scenarios and bags."""

import importlib
import itertools
import os
import shutil
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


# ----- ROS 2 ------------------------------------------------------------------------------------------
# CI runs the suite twice: without ROS (these tests skip, saying why) and with the Jazzy kit sourced and
# ADVPERC_REQUIRE_ROS=1, where a missing ROS 2 piece fails the test instead of skipping it.
REQUIRE_ROS = os.environ.get("ADVPERC_REQUIRE_ROS") == "1"


def need_ros(module: str = "rclpy"):
    """Import a ROS 2 Python module, or skip (fail under ADVPERC_REQUIRE_ROS=1) saying which is missing."""
    try:
        return importlib.import_module(module)
    except ImportError:
        if REQUIRE_ROS:
            pytest.fail(f"{module} cannot be imported though ADVPERC_REQUIRE_ROS=1: is ROS 2 Jazzy sourced?")
        pytest.skip(f"ROS 2 Jazzy is not sourced ({module} missing): the ROS path is untested here")


def need_program(name: str) -> str:
    """A command on PATH (ros2, colcon), or skip (fail under ADVPERC_REQUIRE_ROS=1)."""
    path = shutil.which(name)
    if path is None:
        if REQUIRE_ROS:
            pytest.fail(f"{name} is not on PATH though ADVPERC_REQUIRE_ROS=1")
        pytest.skip(f"{name} is not on PATH (ROS 2 Jazzy not sourced, or colcon not installed)")
    return path


# ROS tests use domain ids 200..232 (test_dds and test_graph take 100..199), a fresh one per test while
# they last; rclpy and the ros2 tools read ROS_DOMAIN_ID, and activate.sh keeps DDS on loopback.
_ros_domains = itertools.cycle(range(200 + (os.getpid() % 3) * 11, 233))


def bare_dds_domains(offset: int):
    """Domain ids 100..199 for a module's bare-DDS tests, from `offset` on by this process's id,
    wrapping round: the DDS group runs one test at a time, so an id comes back only after the test
    that had it is over (a range ending at 199 ran out when the process id put its start at 190)."""
    start = (os.getpid() % 10) * 10 + offset
    return (100 + (start + i) % 100 for i in itertools.count())


@pytest.fixture
def fresh_domain(monkeypatch) -> int:
    """A domain id of its own for a test, also set as ROS_DOMAIN_ID (needs no ROS)."""
    domain = next(_ros_domains)
    monkeypatch.setenv("ROS_DOMAIN_ID", str(domain))
    return domain


@pytest.fixture
def ros_domain(fresh_domain) -> int:
    need_ros()
    return fresh_domain


# The suite runs on `pytest -n auto --dist loadgroup` (README), one xdist group a module, so that its module- and
# session-scoped fixtures (an attack run once and read by many tests) are built on one worker only; every test
# that puts traffic on DDS is in one group, run one after another on one worker, so the per-module domain ids
# above never meet a test of another worker's at the same time.
DDS_MODULES = {"test_dds", "test_graph", "test_ros2", "test_orchestrator_node"}


# The groups that take a worker longest, longest first (`--durations=0` with ROS 2 sourced: the DDS group about
# 570 s, the others 150 s down to 40 s); the rest take less and follow in file order.
LONGEST_GROUPS = ("dds", "test_bundled_scenarios", "test_campaign", "test_obp", "test_junction_scenarios", "test_guided",
                  "test_resume", "test_cli", "test_commonroad")


def _xdist_group(item) -> str:
    module = item.module.__name__.rpartition(".")[2]
    return "dds" if module in DDS_MODULES or "fresh_domain" in item.fixturenames else module


def pytest_configure(config):
    """Groups start in the order pytest_collection_modifyitems gives them (LONGEST_GROUPS first), not in
    xdist's (by number of tests), which started a long group of few tests last, to run on alone."""
    if hasattr(config.option, "loadscopereorder"):
        config.option.loadscopereorder = False


@pytest.hookimpl(tryfirst=True)  # before xdist's own hook, which reads the marks into the groups
def pytest_collection_modifyitems(items):
    """Groups as above, the longest first, so that none starts late and ends long after the other workers."""
    def start(item) -> int:
        group = _xdist_group(item)
        return LONGEST_GROUPS.index(group) if group in LONGEST_GROUPS else len(LONGEST_GROUPS)

    items.sort(key=start)  # stable: each group keeps its order
    for item in items:
        item.add_marker(pytest.mark.xdist_group(_xdist_group(item)))
