"""The rulebook: every rule by name, imported only when asked for (`core.plugins`, as every plug-in).

Adding a rule: a module with a class that has the `base.Rule` protocol, and one line here.
"""

from dataclasses import dataclass
from typing import Any

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
    "forced_braking": "advperc_ros.core.rules.forced_braking:ForcedBraking",
}


RULEBOOK = PluginKind("rule", RULES, type, "a class", plug_ins=False)


def rule_class(name: str) -> type[Rule]:
    """The class of the rule `name` (a key of RULES); a PluginError otherwise."""
    cls: type[Rule] = load(name, RULEBOOK)
    return cls


@dataclass(frozen=True)
class Rulebook:
    """The thresholds one attack judges its rules by: each rule's parameters as its params file sets them
    (`rule.<rule>.<parameter>`), every rule not named here at its defaults. One record, handed from the
    params to the attacked rule, the report's table of every rule and the rule monitor, so all three judge
    a rollout by the same numbers."""

    parameters: tuple[tuple[str, Any], ...] = ()  # (rule name, an instance of that rule's Parameters)

    def rule(self, name: str) -> Rule:
        """The rule `name` built with this rulebook's parameters for it (its defaults when it has none here)."""
        return rule_class(name)(dict(self.parameters).get(name))


DEFAULT_RULEBOOK = Rulebook()


def evaluate_rulebook(inputs: RuleInputs, reference: RuleInputs,
                      rulebook: Rulebook = DEFAULT_RULEBOOK) -> dict[str, RuleValue]:
    """Every registered rule, with `rulebook`'s parameters, on the rollout `inputs`, those that compare with
    the ground truth against `reference` (the ground truth's own inputs, for the ground truth itself): what a
    report says of a rollout whichever rule was attacked, so a collision found also shows it braked hard."""
    return {name: evaluate(rulebook.rule(name), inputs, reference) for name in RULES}
