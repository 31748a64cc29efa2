"""The rulebook: every rule by name, imported only when asked for (`core.plugins`, as every plug-in).

Adding a rule: a module with a class that has the `base.Rule` protocol, and one line here.
"""

from advperc_ros.core.plugins import PluginKind, load
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


RULEBOOK = PluginKind("rule", RULES, type, "a class", plug_ins=False)


def rule_class(name: str) -> type[Rule]:
    """The class of the rule `name` (a key of RULES); a PluginError otherwise."""
    cls: type[Rule] = load(name, RULEBOOK)
    return cls


def evaluate_rulebook(inputs: RuleInputs, reference: RuleInputs) -> dict[str, RuleValue]:
    """Every registered rule, at its default parameters, on the rollout `inputs`, those that compare with the
    ground truth against `reference` (the ground truth's own inputs, for the ground truth itself): what a
    report says of a rollout whichever rule was attacked, so a collision found also shows it braked hard."""
    return {name: evaluate(rule_class(name)(), inputs, reference) for name in RULES}
