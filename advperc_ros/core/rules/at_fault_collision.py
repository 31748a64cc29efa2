"""Rule `at_fault_collision`: the collision rule counting only contacts at the ego's fault.

As nuPlan's no_ego_at_fault_collisions: a contact is excused when the ego is stopped or the agent
hits it from behind (contact.excusable; why no closing-speed test is needed is said there, and what
changes when traffic reacts to the ego). r is
the signed distance to the nearest agent whose contact would count; the rollout's `at_fault_only`
verdict is the same rule (rollout.judge calls the same `excusable`).
"""

from dataclasses import dataclass

import numpy as np

from advperc_ros.core.parameters import Bounds, parameter
from advperc_ros.core.rules.base import ParameterisedRule
from advperc_ros.core.rules.contact import STOPPED_SPEED, excusable
from advperc_ros.core.rules.inputs import RuleInputs


@dataclass(frozen=True)
class AtFaultCollisionParameters:
    """When a contact is not the ego's fault."""

    stopped_speed: float = parameter(
        STOPPED_SPEED, "nuPlan no_ego_at_fault_collisions.py, _ego_is_stopped's stopped_speed_threshold (5e-02 m/s)",
        Bounds(low=0.0, high=5.0))


class AtFaultCollision(ParameterisedRule):
    """Contacts the ego caused: a rear-ending or a stopped ego is not a violation."""

    name = "at_fault_collision"
    meaning = "signed distance to the nearest agent whose contact would be the ego's fault"
    unit = "m"
    needs_reference = False
    Parameters = AtFaultCollisionParameters
    parameters: AtFaultCollisionParameters

    def per_frame(self, inputs: RuleInputs, reference: RuleInputs | None = None) -> np.ndarray:
        excused = excusable(inputs.ego, inputs.ego_length, inputs.agents, self.parameters.stopped_speed,
                            reactive_dt=None if inputs.recorded is None else inputs.dt)
        return np.where(excused, np.inf, inputs.distances).min(axis=1, initial=np.inf)
