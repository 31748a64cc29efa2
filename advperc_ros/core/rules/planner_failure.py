"""Rule `planner_failure`: a frame without a valid plan, or one the planner's fallback answered.

A planner fails a frame when it gives no plan (it raised, hung past the plan timeout, answered
with something not a trajectory or an empty one) or one that cannot be followed (times not
increasing, non-finite poses, not covering the next frame: ego_motion.follow_plan), which ends the
rollout inconclusive at that frame; or when it reports (its stats()) that its solver failed and a
fallback answered. r = 1 at a frame with a valid plan of its own, -1 at a failed one: a rule of
yes or no, with no parameter to set.
"""

import numpy as np

from advperc_ros.core.rules.base import NoParameters, ParameterisedRule
from advperc_ros.core.rules.inputs import RuleInputs


class PlannerFailure(ParameterisedRule):
    """The planner itself failing, which perception errors can provoke and no motion rule shows."""

    name = "planner_failure"
    meaning = "+1 where the planner gave a valid plan of its own, -1 where it gave none, an invalid one or its fallback"
    unit = "+1 / -1"
    needs_reference = False
    Parameters = NoParameters

    def per_frame(self, inputs: RuleInputs, reference: RuleInputs | None = None) -> np.ndarray:
        failed = ~inputs.plan_valid
        failed[list(inputs.fallback_frames or ())] = True
        return np.where(failed, -1.0, 1.0)
