"""At-fault collisions (rule.at_fault_only): hand-built contacts of each kind, through the rollout.

The ego follows a scripted plan (constant speed and heading) so each case is exactly the contact it
names; the agents replay constant-speed lanes.
"""

import numpy as np
import pytest

from advperc_ros.core.perception_errors import PerceptionErrors
from advperc_ros.core.planners.base import Trajectory
from advperc_ros.core.rollout import RolloutConfig, RolloutResult, judge, rollout
from advperc_ros.core.rules.contact import STOPPED_SPEED
from advperc_ros.core.scenario_spec import build_scenario
from advperc_ros.core.tracker import Tracker
from advperc_ros.configs import rollout_config
from advperc_ros.params import AttackParams

LANES = [
    {"id": "east", "centerline": [[-100.0, -1.75], [500.0, -1.75]], "width": 3.5},
    {"id": "east2", "centerline": [[-100.0, 1.75], [500.0, 1.75]], "width": 3.5},
    {"id": "against", "centerline": [[500.0, -1.75], [-100.0, -1.75]], "width": 3.5},  # the ego's lane, backwards
]
CAR = [4.6, 1.9, 1.6]


class Scripted:
    """Drives straight from wherever the ego is, at `speed` and heading `yaw`: the contact under test."""

    def __init__(self, speed, yaw=0.0):
        self.speed, self.yaw = speed, yaw

    def reset(self):
        pass

    def plan(self, t, ego, tracks):
        times = t + 0.1 * np.arange(81)
        d = self.speed * (times - t)
        return Trajectory(t=times, x=ego.x + d * np.cos(self.yaw), y=ego.y + d * np.sin(self.yaw),
                          yaw=np.full(times.size, self.yaw))


def run(ego_speed, agent, at_fault_only, yaw=0.0):
    scenario = build_scenario({"name": "contact", "dt": 0.1, "duration": 6.0, "lanes": LANES,
                               "ego": {"route": ["east"], "start_s": 100.0, "speed": ego_speed},
                               "agents": [{"id": 1, "size": CAR, **agent}]})
    errors = PerceptionErrors.none(*scenario.agents.shape)
    config = RolloutConfig(at_fault_only=at_fault_only)
    return rollout(scenario, errors, Tracker(), Scripted(ego_speed, yaw), config), scenario


CASES = {  # name: (ego speed, agent, ego heading, the ego's fault)
    "rear-ended while moving": (5.0, {"lane": "east", "start_s": 85.0, "speed": 12.0}, 0.0, False),
    "hit head-on while stopped": (0.0, {"lane": "against", "start_s": 470.0, "speed": 8.0}, 0.0, False),
    "drives into a car ahead": (10.0, {"lane": "east", "start_s": 115.0, "speed": 3.0}, 0.0, True),
    "cuts into a car alongside": (8.0, {"lane": "east2", "start_s": 100.0, "speed": 8.0}, 0.1, True),
}


@pytest.mark.parametrize("name", CASES)
def test_only_the_egos_fault_counts_when_asked(name):
    ego_speed, agent, yaw, at_fault = CASES[name]
    every, _ = run(ego_speed, agent, at_fault_only=False, yaw=yaw)
    only, _ = run(ego_speed, agent, at_fault_only=True, yaw=yaw)
    # the contact happens and ends the rollout either way; the signed distances are the same
    assert every.collided and every.min_signed_distance < 0.0 and every.num_frames < 61
    np.testing.assert_array_equal(only.distances, every.distances)
    np.testing.assert_array_equal(only.ego, every.ego)
    assert only.collided is at_fault
    assert every.excused is None


def test_stopped_means_below_the_threshold():
    _, agent, _, _ = CASES["hit head-on while stopped"]
    result, _ = run(0.0, agent, at_fault_only=True)
    assert result.ego[-1, 3] < STOPPED_SPEED and result.excused[-1, 0]


def test_no_contact_excuses_nothing():
    result, _ = run(8.0, {"lane": "east2", "start_s": 100.0, "speed": 8.0}, at_fault_only=True)
    assert not result.collided and not result.excused.any() and result.num_frames == 61


def test_judged_from_ego_and_distances_alone():
    """A result rebuilt from what any backend records (ego states, distances) gets the same verdict."""
    for ego_speed, agent, yaw, at_fault in CASES.values():
        result, scenario = run(ego_speed, agent, at_fault_only=True, yaw=yaw)
        rebuilt = judge(RolloutResult(ego=result.ego, distances=result.distances), scenario,
                        RolloutConfig(at_fault_only=True))
        np.testing.assert_array_equal(rebuilt.excused, result.excused)
        assert rebuilt.collided is at_fault


def test_inconclusive_has_no_verdict_whatever_the_fault():
    result, scenario = run(10.0, CASES["drives into a car ahead"][1], at_fault_only=True)
    result.inconclusive = "planner failed"
    assert not result.collided
    assert result.margin < 0.0 and not result.excused.any()  # the contact is still the ego's fault


@pytest.mark.parametrize("start_s, counted", [(92.0, False), (108.0, True)])
def test_a_near_miss_behind_the_rear_bumper_is_no_step_towards_a_collision(start_s, counted):
    """A car following 3.4 m behind the ego at its speed can only ever rear-end it, so the margin (what
    the approach phase drives down) leaves it out; the same gap ahead is a near miss the ego could close."""
    result, _ = run(8.0, {"lane": "east", "start_s": start_s, "speed": 8.0}, at_fault_only=True)
    assert not result.collided and result.min_signed_distance == pytest.approx(3.4)
    assert result.margin == (pytest.approx(3.4) if counted else np.inf)
    every, _ = run(8.0, {"lane": "east", "start_s": start_s, "speed": 8.0}, at_fault_only=False)
    assert every.margin == every.min_signed_distance


def test_param_threads_to_the_rollout_config():
    assert rollout_config(AttackParams(bag="b").flat()).at_fault_only is False
    assert rollout_config(AttackParams(bag="b").with_values(**{"rule.at_fault_only": True}).flat()).at_fault_only
