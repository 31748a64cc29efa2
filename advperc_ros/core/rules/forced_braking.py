"""Rule `forced_braking`: the ego makes a reactive agent brake harder than a comfortable stop.

The follower's side of phantom braking: under reactive traffic (core.traffic) an agent brakes for the
ego, and braking beyond nuPlan's hardest comfortable braking (ego_lon_acceleration's min_lon_accel,
4.05 m/s^2, the bound hard_braking holds the ego to) is a hazard the ego caused, whether or not the
follower then stops in time. An agent's braking counts while it is off its recording (`traffic.
agent_decelerations`): there it is the model's answer to the ego, not the recorded driver's. r = bound
- the hardest such braking of any agent (the bound itself where none brakes); +inf at every frame of
replayed traffic, where no agent answers the ego.
"""

from dataclasses import dataclass

import numpy as np

from advperc_ros.core.parameters import Bounds, parameter
from advperc_ros.core.rules.base import ParameterisedRule
from advperc_ros.core.rules.inputs import RuleInputs
from advperc_ros.core.rules.motion import MIN_LON_ACCELERATION, MIN_LON_ACCELERATION_SOURCE
from advperc_ros.core.traffic import agent_decelerations


@dataclass(frozen=True)
class ForcedBrakingParameters:
    """The hardest braking the ego may make an agent do."""

    max_deceleration: float = parameter(-MIN_LON_ACCELERATION, f"{MIN_LON_ACCELERATION_SOURCE}, as a deceleration",
                                        Bounds(positive=True, high=30.0))


class ForcedBraking(ParameterisedRule):
    """An agent made to brake hard by the ego: the danger of phantom braking, measured on the car behind."""

    name = "forced_braking"
    meaning = "nuPlan's hardest comfortable braking minus the hardest braking the ego forces on a reactive agent"
    unit = "m/s^2"
    needs_reference = False
    Parameters = ForcedBrakingParameters
    parameters: ForcedBrakingParameters

    def per_frame(self, inputs: RuleInputs, reference: RuleInputs | None = None) -> np.ndarray:
        if inputs.recorded is None:
            return np.full(inputs.num_frames, np.inf)
        braking = agent_decelerations(inputs.agents, inputs.recorded, inputs.dt)
        return self.parameters.max_deceleration - braking.max(axis=1, initial=0.0)
