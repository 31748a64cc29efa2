"""Shared fixtures: the repository's bundled scenarios and bags."""

import importlib
import itertools
import os
import re
import shutil
import sys
from collections import Counter
from pathlib import Path

import pytest

from advperc_ros.ros.bag import read_scenario

REPO = Path(__file__).resolve().parent.parent
TESTS = REPO / "test"

# The tests sit in folders that mirror the package (test/core/search/, test/ros/, ...), and some build on
# another folder's (`from test_cli import write_params` in test/results/): pytest's default import mode puts
# only a test module's own folder (and this one's, for the helpers beside it) on sys.path, so every folder goes
# there now, and a module imports another by its name whichever runs first. That asks for one module of each
# name (pytest says so too, for two test modules of one name, without __init__.py files).
_FOLDERS = sorted({path.parent for path in TESTS.rglob("*.py")} - {TESTS} - set(TESTS.glob("fixtures/**")))
_SHARED_NAMES = sorted(name for name, count in Counter(path.stem for path in TESTS.rglob("*.py")
                                                       if path.parent in {TESTS, *_FOLDERS}).items() if count > 1)
if _SHARED_NAMES:
    raise pytest.UsageError(f"test modules of one name in two folders of test/: {_SHARED_NAMES}; rename one")
sys.path.extend(str(folder) for folder in _FOLDERS if str(folder) not in sys.path)
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


def _worker() -> tuple[int, int]:
    """(this xdist worker's index, the number of workers); (0, 1) without xdist."""
    name = os.environ.get("PYTEST_XDIST_WORKER", "gw0")
    return int(name.removeprefix("gw") or 0), int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))


def _share(low: int, high: int) -> range:
    """This worker's own slice of the domain ids low..high: two workers never use one id, so DDS tests
    may run on every worker at once (each worker runs one test at a time)."""
    index, count = _worker()
    size = (high - low + 1) // max(count, 1)
    return range(low + index * size, low + (index + 1) * size)


# ROS tests use domain ids 200..232, bare-DDS tests 100..199, each worker its own slice of both; a fresh
# id per test while they last. rclpy and the ros2 tools read ROS_DOMAIN_ID, and activate.sh keeps DDS on loopback.
_ros_domains = itertools.cycle(_share(200, 232))


def bare_dds_domains(offset: int):
    """Domain ids of this worker's slice of 100..199 for a module's bare-DDS tests, from `offset` on
    (modulo the slice), wrapping round: a worker runs one test at a time, so an id comes back only
    after the test that had it is over."""
    ids = _share(100, 199)
    return (ids[(offset + i) % len(ids)] for i in itertools.count())


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
# session-scoped fixtures (an attack run once and read by many tests) are built on one worker only. The DDS and
# ROS tests are split over four groups (domain ids are per worker, above, so any two may run at once): bare DDS,
# the ROS 2 tools and nodes, the launches in a colcon workspace, and the one test that runs docs/ros2.md's block.
DDS_MODULES = {"test_dds", "test_graph"}
ROS_MODULES = {"test_ros2", "test_orchestrator_node"}
LONGEST_TEST = "test_readme_ros_section_runs_as_written"
SLOW_TO_FAIL_TEST = "test_a_launch_whose_planner_never_answers_exits_4_naming_who_is_silent"  # the warm-up's minute
# one worker for these, in a workspace of its own (a build takes seconds), the others for ros_workspace and ros: with
# ROS 2 sourced the three take 350-420 s each (`--durations=0`), where ros_workspace alone took 465 s
README_WORKER_TESTS = (LONGEST_TEST, SLOW_TO_FAIL_TEST,
                       "test_ros2_run_with_the_graph_backend_shows_the_whole_graph_and_gives_the_embedded_report")


# The groups that take a worker longest, longest first (`--durations=0` with ROS 2 sourced); the rest take
# less and follow in file order.
LONGEST_GROUPS = ("ros_workspace", "ros_readme", "ros", "dds", "test_junction_scenarios", "test_bundled_scenarios", "test_guided",
                  "test_campaign", "test_resume", "test_cli", "test_commonroad", "test_obp", "test_import_bag",
                  "test_reproduced")


def _xdist_group(item) -> str:
    module = item.module.__name__.rpartition(".")[2]
    if item.originalname in README_WORKER_TESTS:
        return "ros_readme"
    if "workspace" in item.fixturenames:  # `ros2 launch` and `ros2 run` in a colcon workspace: the long ones
        return "ros_workspace"
    if module in ROS_MODULES or "fresh_domain" in item.fixturenames:
        return "ros"
    return "dds" if module in DDS_MODULES else module


def pytest_configure(config):
    """Groups start in the order pytest_collection_modifyitems gives them (LONGEST_GROUPS first), not in
    xdist's (by number of tests), which started a long group of few tests last, to run on alone."""
    if hasattr(config.option, "loadscopereorder"):
        config.option.loadscopereorder = False


# ----- CI's second run, with ROS 2 sourced -----------------------------------------------------------------
# The first run (the README's command) runs every test; those that need ROS skip. The second, with the kit
# sourced and ADVPERC_ROS_RERUN=1, runs again what may behave otherwise with ROS 2 in the environment: every
# test that skipped in the first run (recorded in pytest's cache) and the ROS modules whole. Nothing may skip
# there. The bare-DDS tests are not run again: with `dds.localhost_only` (every test's) our participants
# ignore the kit's CYCLONEDDS_URI, and their domain ids come from the params, not ROS_DOMAIN_ID.
SKIPPED_KEY = "advperc/skipped"
RERUN = os.environ.get("ADVPERC_ROS_RERUN") == "1"



_SKIPPED: set[str] = set()


def pytest_runtest_logreport(report):
    """Remember the tests that skipped (on the controller, which sees every worker's reports; xdist
    names them `<node id>@<group>`)."""
    if report.skipped and not RERUN:
        _SKIPPED.add(re.sub(r"@\w+$", "", report.nodeid))


def pytest_sessionfinish(session):
    cache = getattr(session.config, "cache", None)  # none under `-p no:cacheprovider`
    if not RERUN and not hasattr(session.config, "workerinput") and cache is not None:
        cache.set(SKIPPED_KEY, sorted(_SKIPPED))


def _rerun(item, skipped: set[str]) -> bool:
    module = item.module.__name__.rpartition(".")[2]
    return item.nodeid in skipped or module in ROS_MODULES or "fresh_domain" in item.fixturenames


@pytest.hookimpl(tryfirst=True)  # before xdist's own hook, which reads the marks into the groups
def pytest_collection_modifyitems(config, items):
    """Groups as above, the longest first, so that none starts late and ends long after the other workers;
    in CI's second run only the tests above."""
    if RERUN:
        cache = getattr(config, "cache", None)
        skipped = set(cache.get(SKIPPED_KEY, [])) if cache is not None else set()
        if not skipped:
            raise pytest.UsageError("ADVPERC_ROS_RERUN=1: no record of a first run's skipped tests in the cache "
                                    "(run the suite without ROS first, with the cache provider on)")
        kept = [item for item in items if _rerun(item, skipped)]
        config.hook.pytest_deselected(items=[item for item in items if not _rerun(item, skipped)])
        items[:] = kept

    def start(item) -> int:
        group = _xdist_group(item)
        return LONGEST_GROUPS.index(group) if group in LONGEST_GROUPS else len(LONGEST_GROUPS)

    items.sort(key=start)  # stable: each group keeps its order
    for item in items:
        item.add_marker(pytest.mark.xdist_group(_xdist_group(item)))
