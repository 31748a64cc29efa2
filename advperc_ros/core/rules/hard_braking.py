"""Rule `hard_braking`: the ego decelerating harder than nuPlan's comfort bound.

r = longitudinal acceleration - min_lon_accel, from the executed speeds differentiated as nuPlan
differentiates them (motion.py). The bound is nuPlan's ego_lon_acceleration min_lon_accel, -4.05
m/s^2 (script/config/common/simulation_metric/low_level/ego_lon_acceleration_statistics.yaml), one
of the thresholds of ego_is_comfortable; braking beyond it is what a perception error that makes
the planner brake for nothing shows as.
"""

from dataclasses import dataclass

import numpy as np

from advperc_ros.core.parameters import Bounds, parameter
from advperc_ros.core.rules.base import ParameterisedRule
from advperc_ros.core.rules.inputs import RuleInputs
from advperc_ros.core.rules.motion import MIN_LON_ACCELERATION, MIN_LON_ACCELERATION_SOURCE, longitudinal_acceleration

BRAKING_BOUNDS = Bounds(low=-30.0, high=0.0)  # m/s^2: a braking bound is a deceleration, at most 3 g


@dataclass(frozen=True)
class HardBrakingParameters:
    """The hardest braking that is no violation."""

    min_lon_acceleration: float = parameter(MIN_LON_ACCELERATION, MIN_LON_ACCELERATION_SOURCE,
                                            BRAKING_BOUNDS)


class HardBraking(ParameterisedRule):
    """Braking harder than a comfortable stop: a hazard to whoever follows."""

    name = "hard_braking"
    meaning = "the ego's longitudinal acceleration above nuPlan's hardest comfortable braking"
    unit = "m/s^2"
    needs_reference = False
    Parameters = HardBrakingParameters
    parameters: HardBrakingParameters

    def per_frame(self, inputs: RuleInputs, reference: RuleInputs | None = None) -> np.ndarray:
        return longitudinal_acceleration(inputs) - self.parameters.min_lon_acceleration
