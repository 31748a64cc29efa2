"""The rulebook: every rule by name, imported only when asked for (as the planners' registry).

Adding a rule: a module with a class that has the `base.Rule` protocol, and one line here.
"""

import importlib

from advperc_ros.core.rules.base import Rule

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

