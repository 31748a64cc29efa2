"""TUM's commonroad-reactive-planner through the plug-in interface (advperc_ros.contrib.reactive).

It needs the `reactive` extra, which pins commonroad-io below the main environment's, so these tests
run in a venv of their own (.ci/run) and skip, saying so, where the package is missing.
"""

import dataclasses
import os
import sys
from importlib.util import find_spec

import numpy as np
import pytest

from advperc_ros.core.perception_errors import PerceptionErrors
from advperc_ros.core.planners.base import PlanningContext, planner_stats
from advperc_ros.core.planners.registry import load_planner
from advperc_ros.core.rollout import RolloutConfig, rollout
from advperc_ros.core.scenario_spec import build_scenario
from advperc_ros.core.tracker import Tracker
from advperc_ros.exceptions import PluginError

REACTIVE = "advperc_ros.contrib.reactive:ReactivePlanner"
# the ego at 10 m/s, a car stopped in its lane 45 m ahead, the oncoming lane free
STOPPED_AHEAD = {
    "name": "stopped_ahead",
    "dt": 0.1,
    "duration": 6.0,
    "lanes": [{"id": "east", "centerline": [[-50.0, -1.75], [300.0, -1.75]], "width": 3.5}],
    "ego": {"route": ["east"], "start_s": 50.0, "speed": 10.0},
    "agents": [{"id": 1, "lane": "east", "start_s": 95.0, "speed": 0.0, "size": [4.6, 1.9, 1.6]}],
}


def _context(scenario) -> PlanningContext:
    return PlanningContext(route=scenario.route, lanes=scenario.lanes, dt=0.1, ego_length=4.6, ego_width=1.9)


@pytest.fixture(scope="module")
def stopped_ahead():
    if find_spec("commonroad_rp") is None:
        if os.environ.get("ADVPERC_REQUIRE_REACTIVE") == "1":  # CI's venv for it
            pytest.fail("commonroad_rp cannot be imported though ADVPERC_REQUIRE_REACTIVE=1")
        pytest.skip("commonroad-reactive-planner is not installed (pip install '.[reactive]', in an environment of "
                    "its own: it pins commonroad-io<2025)")
    return build_scenario(STOPPED_AHEAD)


def _rollout(scenario, hide_the_car: bool):
    planner = load_planner(REACTIVE, _context(scenario), {"target_speed": 10.0})
    errors = PerceptionErrors.none(*scenario.agents.shape)
    errors.fn[:] = hide_the_car
    return rollout(scenario, errors, Tracker(), planner, RolloutConfig(at_fault_only=True)), planner


def test_the_reactive_planner_avoids_a_car_it_sees_and_hits_it_when_the_car_is_hidden(stopped_ahead):
    seen, planner = _rollout(stopped_ahead, hide_the_car=False)
    assert seen.inconclusive is None and not seen.collided
    assert seen.num_frames == stopped_ahead.num_frames
    assert planner_stats(planner) is not None  # failures and solve times reach the search log

    hidden, _ = _rollout(stopped_ahead, hide_the_car=True)
    assert hidden.inconclusive is None and hidden.collided  # at fault: it drives into the car from behind


def test_a_rollout_does_not_depend_on_the_rollouts_before_it(stopped_ahead):
    """A search rolls out thousands of error tensors on one planner, a replay or another worker on a
    fresh one: each rollout must be a function of its errors alone. The package keeps its low-speed
    mode from its last call and reads it when it converts the next call's initial state, so a rollout
    that ended slow changed the next one's first plan (an attack found on USA_Peach-4_3 with its
    traffic shifted 1 s did not collide when replayed)."""
    start = stopped_ahead.ego_start  # off the route's centre and heading: the low-speed mode matters
    offset = dataclasses.replace(stopped_ahead, ego_start=dataclasses.replace(start, y=start.y + 0.5, yaw=0.05))
    none = PerceptionErrors.none(*stopped_ahead.agents.shape)
    config = RolloutConfig(at_fault_only=True)
    fresh = rollout(offset, none, Tracker(), load_planner(REACTIVE, _context(offset), {"target_speed": 10.0}), config)

    planner = load_planner(REACTIVE, _context(stopped_ahead), {"target_speed": 10.0})
    creeping = build_scenario({**STOPPED_AHEAD, "duration": 0.5, "ego": {**STOPPED_AHEAD["ego"], "speed": 0.5}})
    slow = rollout(creeping, PerceptionErrors.none(*creeping.agents.shape), Tracker(), planner, config)
    assert slow.ego[-1, 3] < 4.0  # its last call planned in the low-speed mode (below 4 m/s)
    after = rollout(offset, none, Tracker(), planner, config)
    np.testing.assert_array_equal(after.ego, fresh.ego)
    np.testing.assert_array_equal(after.distances, fresh.distances)


def test_rollouts_forked_from_its_snapshots_equal_full_ones(stopped_ahead):
    """Its snapshot() keeps what the package carries from call to call (the low-speed mode among it): rollouts
    forked from the ground truth's snapshots, where the ego brakes to a crawl behind the car, equal full ones."""
    from advperc_ros.core.forks import NATIVE, Forks, PlannerSnapshots
    from advperc_ros.core.rollout import identical

    # the ego sets off at 1 m/s, off the route's centre and heading (where the low-speed mode matters), and
    # passes 4 m/s on the way: forks early in a rollout start in the low-speed mode, which a sampler whose last
    # call was fast has left
    slow = build_scenario({**STOPPED_AHEAD, "duration": 4.0, "ego": {**STOPPED_AHEAD["ego"], "speed": 1.0}})
    scenario = dataclasses.replace(slow, ego_start=dataclasses.replace(slow.ego_start, y=slow.ego_start.y + 0.5, yaw=0.05))
    config = RolloutConfig(at_fault_only=True)
    forked_planner = load_planner(REACTIVE, _context(scenario), {"target_speed": 10.0})
    full_planner = load_planner(REACTIVE, _context(scenario), {"target_speed": 10.0})
    forks = Forks(64 << 20, PlannerSnapshots.of(forked_planner))
    assert forks.planner.how == NATIVE
    frames, agents = scenario.agents.shape
    none = PerceptionErrors.none(frames, agents)
    displaced = none.copy()
    displaced.dy[25:, 0] = 0.8
    tensors = [none, none.with_drop(0, 3, frames - 1), none.with_drop(0, 6, 12), displaced, none.with_drop(0, 4, 30)]
    forked_from, results = [], []
    for errors in tensors:
        results.append(rollout(scenario, errors, Tracker(), forked_planner, config, forks=forks))
        forked_from.append(forks.last_fork)
        assert identical(results[-1], rollout(scenario, errors, Tracker(), full_planner, config)), forks.last_fork
    assert all(frame is not None and frame >= 3 for frame in forked_from[1:]), forked_from
    assert results[0].ego[3, 3] < 4.0 < results[0].ego[-1, 3]  # slow at the first forks, fast at the truth's last call


def test_a_standing_ego_drives_off(stopped_ahead):
    """At exactly 0 m/s the package reads its desired speed from a CommonRoad planning problem, which
    the interface does not carry (it raised AttributeError on three Peachtree recordings)."""
    standing = build_scenario({**STOPPED_AHEAD, "duration": 3.0, "ego": {**STOPPED_AHEAD["ego"], "speed": 0.0}})
    result, _ = _rollout(standing, hide_the_car=False)
    assert result.inconclusive is None and result.num_frames == standing.num_frames
    assert result.ego[-1, 3] > 1.0  # it accelerates towards its target speed


def test_the_reactive_planner_refuses_bad_parameters_as_any_plug_in_does(stopped_ahead):
    with pytest.raises(PluginError, match="target_speed"):
        load_planner(REACTIVE, _context(stopped_ahead), {"target_speed": -1.0})
    with pytest.raises(PluginError, match="unexpected parameter 'speed'"):
        load_planner(REACTIVE, _context(stopped_ahead), {"speed": 10.0})


def test_without_the_package_the_plug_in_says_what_to_install(monkeypatch):
    for name in [n for n in sys.modules if n.split(".")[0] == "commonroad_rp"] + ["commonroad_rp"]:
        monkeypatch.setitem(sys.modules, name, None)  # import commonroad_rp.* now fails, even if imported before
    monkeypatch.delitem(sys.modules, "advperc_ros.contrib.reactive", raising=False)
    scenario = build_scenario(STOPPED_AHEAD)
    with pytest.raises(PluginError, match=r"cannot be imported: needs commonroad-reactive-planner \(pip install "
                                           r"'\.\[reactive\]'"):
        load_planner(REACTIVE, _context(scenario), {})
