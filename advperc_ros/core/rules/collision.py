"""Rule `collision`: the paper's collision rule, the signed distance from the ego to the nearest agent.

r at a frame is the gap between the ego's box and the nearest true agent's box, or minus their
penetration depth when they overlap (contact.CollisionRule). It reads the rollout's own distances,
which the rollout measured with that rule, so the rulebook and the search's verdict are one figure.
"""

import numpy as np

from advperc_ros.core.rules.base import NoParameters, ParameterisedRule
from advperc_ros.core.rules.inputs import RuleInputs


class Collision(ParameterisedRule):
    """The collision rule: every contact counts, whoever caused it (the paper's definition)."""

    name = "collision"
    meaning = "signed distance from the ego's box to the nearest agent's (minus the penetration depth in contact)"
    unit = "m"
    needs_reference = False
    Parameters = NoParameters

    def per_frame(self, inputs: RuleInputs, reference: RuleInputs | None = None) -> np.ndarray:
        return inputs.distances.min(axis=1, initial=np.inf)
