"""Rule `driving_direction`: driving against the direction of the lane the ego is in.

As nuPlan's driving_direction_compliance: the ego's movement along the centreline of the lane it
is in (the direction the centreline's points run), summed over the last `time_horizon`; movement
counts only while the ego stays in one lane (entering another starts the sum afresh), and off every
lane it is 0. nuPlan tolerates up to 2 m against the lane and fails the drive beyond
driving_direction_violation_threshold, 6 m, within time_horizon, 1 s (script/config/common/
simulation_metric/high_level/driving_direction_compliance_statistics.yaml). r = that threshold +
the movement along the lane (m): below 0 when the ego has moved more than 6 m the wrong way in a
second.
"""

from dataclasses import dataclass

import numpy as np

from advperc_ros.core.parameters import Bounds, parameter
from advperc_ros.core.rules.base import ParameterisedRule
from advperc_ros.core.rules.inputs import RuleInputs
from advperc_ros.core.rules.lanes import ROUTE_WIDTH, ROUTE_WIDTH_BOUNDS, ROUTE_WIDTH_SOURCE, containing_lane, road

NUPLAN_CONFIG = "nuPlan driving_direction_compliance_statistics.yaml"


@dataclass(frozen=True)
class DrivingDirectionParameters:
    """How far against the lane is a violation, over how long."""

    violation_threshold: float = parameter(6.0, f"{NUPLAN_CONFIG}: driving_direction_violation_threshold (m)",
                                                Bounds(positive=True, high=1000.0))
    time_horizon: float = parameter(1.0, f"{NUPLAN_CONFIG}: time_horizon (s)", Bounds(positive=True, high=60.0))
    route_width: float = parameter(ROUTE_WIDTH, ROUTE_WIDTH_SOURCE, ROUTE_WIDTH_BOUNDS)


class DrivingDirection(ParameterisedRule):
    """Wrong-way driving: onto the oncoming lane and along it."""

    name = "driving_direction"
    meaning = "nuPlan's 6 m plus the ego's movement along its lane's direction over the last second"
    unit = "m"
    needs_reference = False
    Parameters = DrivingDirectionParameters
    parameters: DrivingDirectionParameters

    def per_frame(self, inputs: RuleInputs, reference: RuleInputs | None = None) -> np.ndarray:
        p = self.parameters
        lane, station = containing_lane(inputs.ego[:, :2], road(inputs, p.route_width))
        same_lane = (lane[1:] >= 0) & (lane[1:] == lane[:-1])
        moved = np.concatenate([[0.0], np.where(same_lane, np.diff(station), 0.0)])
        horizon = int(round(p.time_horizon / inputs.dt))
        total = np.cumsum(moved)
        # the movement of frames k - horizon .. k (nuPlan's window), each frame's own step included
        over_horizon = total - np.concatenate([np.zeros(horizon + 1), total[: -horizon - 1]])[: total.size]
        return p.violation_threshold + over_horizon
