"""Rule `phantom_braking`: braking hard for nothing, against the ground truth's rollout.

A frame brakes for nothing when the ego decelerates beyond the hard-braking bound, the ground
truth's rollout of the same scenario (the stack on error-free perception) brakes less hard within
`window` of that frame, and no true agent in the ego's path needs such braking: the deceleration
that would just avoid it (its DRAC, the deceleration rate to avoid a crash: closing speed squared
over twice the gap) is below the bound. r = the ego's longitudinal acceleration - the harder of the
bound and the ground truth's hardest braking in the window (m/s^2); +inf where a true agent ahead
explains the braking.

Defaults: the bound is 0.3 g (2.94 m/s^2), the deceleration above which studies of drivers' braking
count a hard braking event (Naito et al. 2009, Miyajima et al. 2011; the Institute of Transportation
Engineers' 3.0 m/s^2 is next to it), so a planner that brakes at its limit for a car that is not there
shows, where nuPlan's comfort bound of 4.05 m/s^2 (rule `hard_braking`) is beyond what many planners
ever command. The DRAC test is the surrogate safety measure of Almqvist, Hyden and Risser (1991): an
agent ahead that the ego closes on so fast that braking this hard is needed explains it, one it follows
at a steady gap does not. The window is 1 s either side, a judgment: wide enough that a braking the
ground truth also has, come a few frames earlier or later under perception errors, is not counted,
short against a scenario's tens of seconds. An agent is in the ego's path when its centre lies ahead
of the ego's front bumper and within half the two widths of the ego's heading line.
"""

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import minimum_filter1d

from advperc_ros.core.parameters import Bounds, parameter
from advperc_ros.core.rules.base import ParameterisedRule
from advperc_ros.core.rules.hard_braking import BRAKING_BOUNDS
from advperc_ros.core.rules.inputs import RuleInputs, held
from advperc_ros.core.rules.motion import longitudinal_acceleration


@dataclass(frozen=True)
class PhantomBrakingParameters:
    """What braking counts as hard, and over what time the ground truth's own braking excuses it."""

    min_lon_acceleration: float = parameter(-2.94, "0.3 g, a hard braking event in studies of drivers' braking "
                                                   "(Naito et al. 2009) (m/s^2)", BRAKING_BOUNDS)
    window: float = parameter(1.0, "a judgment: a few frames' shift of a braking the ground truth has (s)",
                              Bounds(low=0.0, high=60.0))


class PhantomBraking(ParameterisedRule):
    """Hard braking the ground truth does not need and no agent ahead explains: the failure a ghost
    or a mislocated car causes, which the collision rule never sees."""

    name = "phantom_braking"
    meaning = "the ego's braking beyond both the hard-braking bound and the ground truth's, no agent ahead needing it"
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
        return np.where(agent_ahead_needs(inputs, -p.min_lon_acceleration), np.inf, acceleration - excused)


def agent_ahead_needs(inputs: RuleInputs, deceleration: float) -> np.ndarray:
    """(K,) whether a true agent in the ego's path needs at least `deceleration` (m/s^2) to be avoided:
    its DRAC, the closing speed squared over twice the gap to the front bumper (a gap closed: contact)."""
    ego, agents = inputs.ego, inputs.agents
    x, y, yaw, v = (ego[:, i : i + 1] for i in range(4))
    dx, dy = agents.x - x, agents.y - y
    along = dx * np.cos(yaw) + dy * np.sin(yaw)
    across = -dx * np.sin(yaw) + dy * np.cos(yaw)
    gap = along - 0.5 * (inputs.ego_length + agents.length)
    in_path = agents.valid & (along > 0.5 * inputs.ego_length) & (np.abs(across) < 0.5 * (inputs.ego_width + agents.width))
    closing = np.maximum(v - (agents.vx * np.cos(yaw) + agents.vy * np.sin(yaw)), 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        drac = np.where(gap > 0.0, closing**2 / (2.0 * gap), np.inf)
    return np.any(in_path & (drac >= deceleration), axis=1)
