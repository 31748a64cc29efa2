"""Rule `comfort`: nuPlan's ego_is_comfortable, every one of its six bounds at once.

nuPlan's ego is comfortable when, at every sample, its longitudinal acceleration lies in
[min_lon_accel, max_lon_accel], and its lateral acceleration, yaw rate, yaw acceleration,
longitudinal jerk and jerk magnitude lie within their +-bounds (ego_is_comfortable.py over the
six low-level metrics). r at a frame is the smallest of the six margins, each as a fraction of its
bound (1 at rest, 0 at a bound, < 0 beyond), so that quantities of different units compare. The
bounds are nuPlan's defaults, script/config/common/simulation_metric/low_level/*_statistics.yaml;
the quantities are differentiated as nuPlan does it (motion.py).
"""

from dataclasses import dataclass

import numpy as np

from advperc_ros.core.parameters import Bounds, parameter
from advperc_ros.core.rules.base import ParameterisedRule
from advperc_ros.core.rules.hard_braking import BRAKING_BOUNDS
from advperc_ros.core.rules.inputs import RuleInputs
from advperc_ros.core.rules.motion import MIN_LON_ACCELERATION, MIN_LON_ACCELERATION_SOURCE, ego_motion

CONFIG = "nuPlan low_level/{}_statistics.yaml: {}"


@dataclass(frozen=True)
class ComfortParameters:
    """nuPlan's comfort bounds."""

    min_lon_acceleration: float = parameter(MIN_LON_ACCELERATION, MIN_LON_ACCELERATION_SOURCE,
                                            BRAKING_BOUNDS)
    max_lon_acceleration: float = parameter(2.40, CONFIG.format("ego_lon_acceleration", "max_lon_accel (m/s^2)"),
                                            Bounds(positive=True, high=30.0))
    max_abs_lat_acceleration: float = parameter(
        4.89, CONFIG.format("ego_lat_acceleration", "max_abs_lat_accel (m/s^2)"), Bounds(positive=True, high=30.0))
    max_abs_yaw_rate: float = parameter(0.95, CONFIG.format("ego_yaw_rate", "max_abs_yaw_rate (rad/s)"),
                                        Bounds(positive=True, high=10.0))
    max_abs_yaw_acceleration: float = parameter(
        1.93, CONFIG.format("ego_yaw_acceleration", "max_abs_yaw_accel (rad/s^2)"), Bounds(positive=True, high=50.0))
    max_abs_lon_jerk: float = parameter(4.13, CONFIG.format("ego_lon_jerk", "max_abs_lon_jerk (m/s^3)"),
                                        Bounds(positive=True, high=100.0))
    max_abs_jerk_magnitude: float = parameter(8.37, CONFIG.format("ego_jerk", "max_abs_mag_jerk (m/s^3)"),
                                              Bounds(positive=True, high=100.0))


class Comfort(ParameterisedRule):
    """A drive no passenger would accept: harsh acceleration, swerving, jerks."""

    name = "comfort"
    meaning = "the smallest margin to nuPlan's six comfort bounds, each as a fraction of its bound"
    unit = "fraction of the bound"
    needs_reference = False
    Parameters = ComfortParameters
    parameters: ComfortParameters

    def per_frame(self, inputs: RuleInputs, reference: RuleInputs | None = None) -> np.ndarray:
        return np.min(list(comfort_margins(inputs, self.parameters).values()), axis=0)


def comfort_margins(inputs: RuleInputs, p: ComfortParameters) -> dict[str, np.ndarray]:
    """Each quantity's (K,) margin to its bound as a fraction of the bound, by name."""
    motion = ego_motion(inputs)
    lon = motion.lon_acceleration
    margins = {
        "braking": 1.0 - lon / p.min_lon_acceleration,
        "acceleration": 1.0 - lon / p.max_lon_acceleration,
    }
    for name, values, bound in (("lat_acceleration", motion.lat_acceleration, p.max_abs_lat_acceleration),
                                ("yaw_rate", motion.yaw_rate, p.max_abs_yaw_rate),
                                ("yaw_acceleration", motion.yaw_acceleration, p.max_abs_yaw_acceleration),
                                ("lon_jerk", motion.lon_jerk, p.max_abs_lon_jerk),
                                ("jerk_magnitude", motion.jerk_magnitude, p.max_abs_jerk_magnitude)):
        margins[name] = 1.0 - np.abs(values) / bound
    return margins
