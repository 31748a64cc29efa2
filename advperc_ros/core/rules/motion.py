"""The ego's executed motion differentiated as nuPlan's comfort metrics do it, for the motion rules.

nuPlan (nuplan/planning/metrics/utils/state_extractors.py) smooths and differentiates every
quantity with a Savitzky-Golay filter of polynomial order 2 (3 for the yaw acceleration) and rounds
to 8 decimals: the acceleration smoothed over 8 samples, the jerk its derivative over 15, the yaw
rate and yaw acceleration derivatives of the unwrapped heading over 5. nuPlan reads the
acceleration the simulator integrated; a rollout here records speeds only, so the longitudinal
acceleration is the speed's first derivative over the acceleration's 8 samples, and the lateral
one the centripetal v * yaw rate, smoothed as nuPlan smooths its acceleration.

One departure: at a drive's first and last frames, where no window centres on the frame, nuPlan's
filter evaluates the derivative of the polynomial fitted to the edge window at the window's end,
which overstates a braking that ends a drive (a speed falling at exactly 3.0 m/s^2 over the last 5
frames read -4.53 m/s^2: a phantom or hard braking the ego never did). Here those frames hold the
value of the nearest frame a window centres on (`savgol`), so a violation is read only from samples
on both sides of it.
"""

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from scipy.signal import savgol_filter

if TYPE_CHECKING:  # the rollout's at-fault test reads this module, and the rules' inputs read the rollout
    from advperc_ros.core.rules.inputs import RuleInputs

ACCELERATION_WINDOW = 8  # samples: extract_ego_acceleration's window_length
JERK_WINDOW = 15  # samples: extract_ego_jerk's window_length
YAW_WINDOW = 5  # samples: approximate_derivatives' window_length, which extract_ego_yaw_rate keeps
DECIMALS = 8  # nuPlan's rounding of every extracted quantity
MIN_LON_ACCELERATION = -4.05  # m/s^2, nuPlan's ego_lon_acceleration min_lon_accel: the hardest comfortable braking
MIN_LON_ACCELERATION_SOURCE = "nuPlan ego_lon_acceleration_statistics.yaml: min_lon_accel (m/s^2)"


def savgol(values: np.ndarray, window: int, order: int, deriv: int, dt: float) -> np.ndarray:
    """nuPlan's filter: the window cut to the samples there are; too few samples to fit the
    polynomial give zeros (nothing to differentiate). The frames within half a window of either end hold
    the value of the nearest frame a window centres on (the module's docstring says why)."""
    window = min(window, values.size)
    if window <= order:
        return np.zeros_like(values)
    smoothed = savgol_filter(values, window_length=window, polyorder=order, deriv=deriv, delta=dt)
    edge = window // 2
    centred = np.clip(np.arange(values.size), edge, max(edge, values.size - 1 - edge))
    return np.round(smoothed[centred], DECIMALS)


def speed_acceleration(speeds: np.ndarray, dt: float) -> np.ndarray:
    """(K,) m/s^2: the first derivative of speeds `speeds` sampled every `dt` s, as nuPlan smooths it."""
    return savgol(speeds, ACCELERATION_WINDOW, 2, 1, dt)


def longitudinal_acceleration(inputs: "RuleInputs") -> np.ndarray:
    """(K,) m/s^2 along the ego's heading, at every frame."""
    return speed_acceleration(inputs.ego[:, 3], inputs.dt)


@dataclass(frozen=True)
class EgoMotion:
    """The six quantities of nuPlan's ego_is_comfortable, per frame of the executed drive."""

    lon_acceleration: np.ndarray  # m/s^2
    lat_acceleration: np.ndarray  # m/s^2
    yaw_rate: np.ndarray  # rad/s
    yaw_acceleration: np.ndarray  # rad/s^2
    lon_jerk: np.ndarray  # m/s^3
    jerk_magnitude: np.ndarray  # m/s^3, the derivative of the acceleration's magnitude (as nuPlan's)


def ego_motion(inputs: "RuleInputs") -> EgoMotion:
    """The executed drive's dynamics, differentiated as nuPlan differentiates them."""
    dt = inputs.dt
    heading = np.unwrap(inputs.ego[:, 2])
    lon = longitudinal_acceleration(inputs)
    yaw_rate = savgol(heading, YAW_WINDOW, 2, 1, dt)
    lat = savgol(inputs.ego[:, 3] * yaw_rate, ACCELERATION_WINDOW, 2, 0, dt)
    return EgoMotion(
        lon_acceleration=lon, lat_acceleration=lat, yaw_rate=yaw_rate,
        yaw_acceleration=savgol(heading, YAW_WINDOW, 3, 2, dt),
        lon_jerk=savgol(lon, JERK_WINDOW, 2, 1, dt),
        jerk_magnitude=savgol(np.hypot(lon, lat), JERK_WINDOW, 2, 1, dt),
    )
