"""Rule `drivable_area`: the ego's box leaving the road by more than nuPlan's tolerance.

As nuPlan's drivable_area_compliance: a corner of the ego's box may stray outside the drivable
area by less than max_violation_threshold, 0.3 m (script/config/common/simulation_metric/
high_level/drivable_area_compliance_statistics.yaml). The drivable area is the union of the
scenario's lanes, each a corridor of its width about its centreline (lanes.py), or a corridor
about the route when the scenario has no lanes. r = max_violation_threshold - the farthest corner's
distance outside the drivable area.
"""

from dataclasses import dataclass

import numpy as np

from advperc_ros.core.geometry import box_corners
from advperc_ros.core.parameters import Bounds, parameter
from advperc_ros.core.rules.base import ParameterisedRule
from advperc_ros.core.rules.inputs import RuleInputs
from advperc_ros.core.rules.lanes import ROUTE_WIDTH, ROUTE_WIDTH_BOUNDS, ROUTE_WIDTH_SOURCE, outside_road, road


@dataclass(frozen=True)
class DrivableAreaParameters:
    """How far off the road a corner may be, and the road of a scenario without lanes."""

    max_violation: float = parameter(
        0.3, "nuPlan drivable_area_compliance_statistics.yaml: max_violation_threshold (m)", Bounds(low=0.0, high=10.0))
    route_width: float = parameter(ROUTE_WIDTH, ROUTE_WIDTH_SOURCE, ROUTE_WIDTH_BOUNDS)


class DrivableArea(ParameterisedRule):
    """Off the road: onto the kerb, the verge or into a parked row."""

    name = "drivable_area"
    meaning = "nuPlan's 0.3 m tolerance minus the ego's farthest corner's distance outside the lanes"
    unit = "m"
    needs_reference = False
    Parameters = DrivableAreaParameters
    parameters: DrivableAreaParameters

    def per_frame(self, inputs: RuleInputs, reference: RuleInputs | None = None) -> np.ndarray:
        ego = inputs.ego
        corners = box_corners(ego[:, 0], ego[:, 1], ego[:, 2], inputs.ego_length, inputs.ego_width)  # (K, 4, 2)
        outside = outside_road(corners, road(inputs, self.parameters.route_width))
        return self.parameters.max_violation - outside.max(axis=1, initial=0.0)
