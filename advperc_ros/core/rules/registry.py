"""The rulebook: every rule by name, imported only when asked for (as the planners' registry).

Adding a rule: a module with a class that has the `base.Rule` protocol, and one line here.
"""

import importlib

from advperc_ros.core.rules.base import Rule, RuleValue, evaluate
from advperc_ros.core.rules.inputs import RuleInputs

RULES = {
    "collision": "advperc_ros.core.rules.collision:Collision",
    "at_fault_collision": "advperc_ros.core.rules.at_fault_collision:AtFaultCollision",
    "time_to_collision": "advperc_ros.core.rules.time_to_collision:TimeToCollision",
    "hard_braking": "advperc_ros.core.rules.hard_braking:HardBraking",
    "comfort": "advperc_ros.core.rules.comfort:Comfort",
    "phantom_braking": "advperc_ros.core.rules.phantom_braking:PhantomBraking",
    "drivable_area": "advperc_ros.core.rules.drivable_area:DrivableArea",
    "driving_direction": "advperc_ros.core.rules.driving_direction:DrivingDirection",
    "progress": "advperc_ros.core.rules.progress:Progress",
    "planner_failure": "advperc_ros.core.rules.planner_failure:PlannerFailure",
}


def rule_class(name: str) -> type[Rule]:
    """The class of the rule `name` (a key of RULES)."""
    if name not in RULES:
        raise ValueError(f"unknown rule '{name}' (known: {', '.join(RULES)})")
    module_name, _, class_name = RULES[name].partition(":")
    return getattr(importlib.import_module(module_name), class_name)



def evaluate_rulebook(inputs: RuleInputs, reference: RuleInputs) -> dict[str, RuleValue]:
    """Every registered rule, at its default parameters, on the rollout `inputs`, those that compare with the
    ground truth against `reference` (the ground truth's own inputs, for the ground truth itself): what a
    report says of a rollout whichever rule was attacked, so a collision found also shows it braked hard."""
    return {name: evaluate(rule_class(name)(), inputs, reference) for name in RULES}
