"""Rule `time_to_collision`: nuPlan's time_to_collision_within_bound.

Definition (nuplan/planning/metrics/evaluation_metrics/common/time_to_collision_within_bound.py):
at every frame the ego and the agents are projected at constant velocity, each along its heading
at its speed, in steps of `time_step` up to (not including) `time_horizon`; the frame's time to
collision is the first step at which the ego's box meets an agent's, +inf when none does within
the horizon or the ego is stopped, and 0 while the ego is in a contact at its fault. An agent
counts when it is ahead (within `ahead_angle` of the ego's heading) or, while the ego is not within
one lane (changing lanes, off the road), when it is not behind (beyond `behind_angle`); an agent
that has touched the ego counts no more. nuPlan passes when every frame's time exceeds
`least_min_ttc`; r = time to collision - least_min_ttc. Defaults from nuPlan's
script/config/common/simulation_metric/high_level/time_to_collision_within_bound_statistics.yaml
(time_step_size 0.1 s, time_horizon 3.0 s, least_min_ttc 0.95 s) and the code's own (a 5e-03 m/s
stopped speed, is_agent_ahead's 30 deg, is_agent_behind's 150 deg). Differences: the centre of
the box stands for nuPlan's rear axle in the angle tests, and "within one lane" means the ego's
four corners in one lane corridor (nuPlan: in common or connected lanes).
"""

from dataclasses import dataclass

import numpy as np

from advperc_ros.core.geometry import box_corners, signed_box_distance_pairs, wrap_angle
from advperc_ros.core.parameters import Bounds, parameter
from advperc_ros.core.rules.base import ParameterisedRule
from advperc_ros.core.rules.contact import excusable
from advperc_ros.core.rules.inputs import RuleInputs
from advperc_ros.core.rules.lanes import ROUTE_WIDTH, containing_lane, road

NUPLAN_CONFIG = "nuPlan time_to_collision_within_bound_statistics.yaml"


@dataclass(frozen=True)
class TimeToCollisionParameters:
    """The bound on the time to collision and how it is projected."""

    least_min_ttc: float = parameter(0.95, f"{NUPLAN_CONFIG}: least_min_ttc (s)", Bounds(low=0.0, high=60.0))
    time_step: float = parameter(0.1, f"{NUPLAN_CONFIG}: time_step_size (s)", Bounds(positive=True, high=10.0))
    time_horizon: float = parameter(3.0, f"{NUPLAN_CONFIG}: time_horizon (s)", Bounds(positive=True, high=60.0))
    stopped_speed: float = parameter(5e-3, "nuPlan compute_time_to_collision: stopped_speed_threshold (m/s)",
                                    Bounds(low=0.0, high=5.0))
    ahead_angle: float = parameter(30.0, "nuPlan idm/utils.py is_agent_ahead: angle_tolerance (deg)",
                                 Bounds(positive=True, high=180.0))
    behind_angle: float = parameter(150.0, "nuPlan idm/utils.py is_agent_behind: angle_tolerance (deg)",
                                  Bounds(positive=True, high=180.0))


class TimeToCollision(ParameterisedRule):
    """Too little time before a collision if nobody changed speed or heading: near misses that a
    signed distance alone does not tell from a safe pass."""

    name = "time_to_collision"
    meaning = "time until the ego's box meets an agent's at constant velocities, minus nuPlan's bound"
    unit = "s"
    needs_reference = False
    Parameters = TimeToCollisionParameters
    parameters: TimeToCollisionParameters

    def per_frame(self, inputs: RuleInputs, reference: RuleInputs | None = None) -> np.ndarray:
        return time_to_collision(inputs, self.parameters) - self.parameters.least_min_ttc


def time_to_collision(inputs: RuleInputs, p: TimeToCollisionParameters) -> np.ndarray:
    """(K,) s: each frame's time to collision, +inf when none within the horizon."""
    ego, agents = inputs.ego, inputs.agents
    x, y, yaw, v = (ego[:, i : i + 1] for i in range(4))
    contact = inputs.distances < 0.0
    at_fault = contact & ~excusable(ego, inputs.ego_length, agents)
    touched_before = np.logical_or.accumulate(contact, axis=0)
    angle = np.abs(wrap_angle(np.arctan2(agents.y - y, agents.x - x) - yaw))
    corners = box_corners(ego[:, 0], ego[:, 1], ego[:, 2], inputs.ego_length, inputs.ego_width)  # (K, 4, 2)
    lane, _ = containing_lane(corners, road(inputs, ROUTE_WIDTH))
    within_one_lane = (lane[:, :1] >= 0) & np.all(lane == lane[:, :1], axis=1, keepdims=True)
    relevant = agents.valid & ~touched_before & (v > p.stopped_speed) & (
        (angle < np.deg2rad(p.ahead_angle)) | (~within_one_lane & (angle <= np.deg2rad(p.behind_angle))))
    times = np.arange(p.time_step, p.time_horizon, p.time_step)
    frames, slots = np.nonzero(relevant)
    pairs = np.empty((2, frames.size, times.size, 5))
    ego_step = ego[frames, 3:4] * times  # (M, S): distance travelled by each step
    pairs[0, ..., 0] = ego[frames, 0:1] + np.cos(ego[frames, 2:3]) * ego_step
    pairs[0, ..., 1] = ego[frames, 1:2] + np.sin(ego[frames, 2:3]) * ego_step
    pairs[0, ..., 2] = ego[frames, 2:3]
    pairs[0, ..., 3:] = inputs.ego_length, inputs.ego_width
    agent_yaw = agents.yaw[frames, slots][:, None]
    agent_step = np.hypot(agents.vx, agents.vy)[frames, slots][:, None] * times
    pairs[1, ..., 0] = agents.x[frames, slots][:, None] + np.cos(agent_yaw) * agent_step
    pairs[1, ..., 1] = agents.y[frames, slots][:, None] + np.sin(agent_yaw) * agent_step
    pairs[1, ..., 2] = agent_yaw
    pairs[1, ..., 3] = agents.length[frames, slots][:, None]
    pairs[1, ..., 4] = agents.width[frames, slots][:, None]
    meets = signed_box_distance_pairs(pairs.reshape(2, -1, 5)).reshape(frames.size, times.size) <= 0.0
    first = np.where(meets.any(axis=1), times[np.argmax(meets, axis=1)], np.inf)
    ttc = np.full(inputs.num_frames, np.inf)
    np.minimum.at(ttc, frames, first)
    return np.where(at_fault.any(axis=1), 0.0, ttc)
