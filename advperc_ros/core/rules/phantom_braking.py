"""Rule `phantom_braking`: braking hard for nothing, against the ground truth's rollout.

A frame brakes for nothing when the ego decelerates beyond the hard-braking bound, the ground
truth's rollout of the same scenario (the stack on error-free perception) brakes less hard within
`window` of that frame, and no true agent is in the ego's path within `time_gap` of travel ahead.
r = the ego's longitudinal acceleration - the harder of the bound and the ground truth's hardest
braking in the window (m/s^2); +inf where a true agent ahead explains the braking.

Defaults: the bound is nuPlan's comfort min_lon_accel (-4.05 m/s^2, as hard_braking); the time
gap is the common two-second following rule (a driver keeps at least 2 s behind the vehicle ahead,
e.g. the UK Highway Code rule 126), so braking for an agent nearer than that is explained; the
window is 1 s either side, a judgment: wide enough that a braking the ground truth also has, come
a few frames earlier or later under perception errors, is not counted, short against a scenario's
tens of seconds. An agent
is in the ego's path when its centre lies ahead of the ego's front bumper and within half the two
widths of the ego's heading line.
"""

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import minimum_filter1d

from advperc_ros.core.rules.base import ParameterisedRule, parameter
from advperc_ros.core.rules.hard_braking import MIN_LON_ACCELERATION, MIN_LON_ACCELERATION_SOURCE
from advperc_ros.core.rules.inputs import RuleInputs, held
from advperc_ros.core.rules.motion import longitudinal_acceleration


@dataclass(frozen=True)
class PhantomBrakingParameters:
    """What braking counts as hard, and what explains it."""

    min_lon_acceleration: float = parameter(MIN_LON_ACCELERATION, MIN_LON_ACCELERATION_SOURCE)
    time_gap: float = parameter(2.0, "the two-second following rule (UK Highway Code rule 126) (s)")
    window: float = parameter(1.0, "a judgment: a few frames' shift of a braking the ground truth has (s)")


class PhantomBraking(ParameterisedRule):
    """Hard braking the ground truth does not need and no agent ahead explains: the failure a ghost
    or a mislocated car causes, which the collision rule never sees."""

    name = "phantom_braking"
    meaning = "the ego's braking beyond both the hard-braking bound and the ground truth's, with no agent ahead"
    unit = "m/s^2"
    needs_reference = True
    Parameters = PhantomBrakingParameters
    parameters: PhantomBrakingParameters

    def per_frame(self, inputs: RuleInputs, reference: RuleInputs | None = None) -> np.ndarray:
        assert reference is not None  # base.evaluate checks it
        p = self.parameters
        acceleration = longitudinal_acceleration(inputs)
        half = int(round(p.window / inputs.dt))
        truth = longitudinal_acceleration(reference)
        # the ground truth's hardest braking within the window of each frame, its frames beyond ours included
        truth = held(truth, max(truth.size, inputs.num_frames))
        truth_hardest = minimum_filter1d(truth, size=2 * half + 1, mode="nearest")[: inputs.num_frames]
        excused = np.minimum(p.min_lon_acceleration, truth_hardest)
        return np.where(agent_ahead_within(inputs, p.time_gap), np.inf, acceleration - excused)


def agent_ahead_within(inputs: RuleInputs, time_gap: float) -> np.ndarray:
    """(K,) whether a true agent is in the ego's path, its gap to the front bumper under `time_gap`
    of the ego's travel."""
    ego, agents = inputs.ego, inputs.agents
    x, y, yaw, v = (ego[:, i : i + 1] for i in range(4))
    dx, dy = agents.x - x, agents.y - y
    along = dx * np.cos(yaw) + dy * np.sin(yaw)
    across = -dx * np.sin(yaw) + dy * np.cos(yaw)
    gap = along - 0.5 * (inputs.ego_length + agents.length)
    in_path = agents.valid & (along > 0.5 * inputs.ego_length) & (np.abs(across) < 0.5 * (inputs.ego_width + agents.width))
    return np.any(in_path & (gap < v * time_gap), axis=1)
