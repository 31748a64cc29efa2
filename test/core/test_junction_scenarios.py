"""The T-junction scenarios under the optimisation-based planner: the ego completes its turn behind
the car it must yield to, typical errors do not make it collide, and hiding that car does."""

import numpy as np
import pytest

from advperc_ros.backends.embedded import Stack
from advperc_ros.configs import core_configs
from advperc_ros.core.perception_errors import PerceptionErrors
from advperc_ros.core.geometry import wrap_angle
from advperc_ros.core.typical import TypicalErrorConfig, sample_typical_errors
from advperc_ros.params import load_params
from advperc_ros.ros.bag import read_scenario

# scenario -> (the lane the turn ends in, the agent id the ego must yield to)
JUNCTIONS = {
    "obp_left_turn": ("side_north", 1),
    "obp_right_turn": ("west_exit", 1),
}
TYPICAL_SAMPLES = 5  # each ObP rollout takes seconds; `advperc check-typical` runs the paper's 100


@pytest.fixture(scope="module", params=sorted(JUNCTIONS))
def junction(request, repo):
    name = request.param
    scenario = read_scenario(repo / "bags" / name)
    stack = Stack(scenario, core_configs(load_params(repo / "config" / f"{name}.yaml")))
    target_lane, yield_to = JUNCTIONS[name]
    slot = int(np.flatnonzero(scenario.agents.ids[0] == yield_to)[0])
    lane = next(lane for lane in scenario.lanes if lane.id == target_lane)
    truth = stack.rollout(PerceptionErrors.none(*scenario.agents.shape))
    return scenario, stack, lane, slot, truth, stack.planner.failures


def test_ground_truth_turns_into_the_target_lane_behind_the_yielded_to_car(junction):
    scenario, _, lane, slot, truth, failures = junction
    assert truth.inconclusive is None and truth.num_frames == scenario.num_frames
    assert truth.min_signed_distance > 0.3
    assert failures == 0
    station, lateral = lane.centerline.project(truth.ego_xy)
    assert station[-1] > 10.0 and abs(lateral[-1]) < 0.5  # well inside the target lane, centred
    assert abs(wrap_angle(truth.ego[-1, 2] - lane.centerline.heading(station[-1]))) < 0.05
    # where the two paths come closest, the yielded-to car was there first
    car = np.stack([scenario.agents.x[:, slot], scenario.agents.y[:, slot]], axis=1)
    gaps = np.linalg.norm(truth.ego_xy[:, None, :] - car[None, :, :], axis=-1)
    ego_frame, car_frame = np.unravel_index(np.argmin(gaps), gaps.shape)
    assert car_frame < ego_frame


def test_typical_errors_cause_no_collision(junction):
    scenario, stack, *_ = junction
    rng = np.random.default_rng(7)
    for _ in range(TYPICAL_SAMPLES):
        result = stack.rollout(sample_typical_errors(scenario.agents.shape, rng, TypicalErrorConfig()))
        assert result.inconclusive is None
        assert result.min_signed_distance > 0.0


def test_hiding_the_yielded_to_car_makes_it_collide_with_that_car(junction):
    scenario, stack, _, slot, *_ = junction
    num_frames, num_agents = scenario.agents.shape
    result = stack.rollout(PerceptionErrors.none(num_frames, num_agents).with_drop(slot, 0, num_frames - 1))
    assert result.collided
    assert int(np.argmin(result.distances[-1])) == slot
