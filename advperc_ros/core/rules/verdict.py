"""The attacked rule: how every rollout of a search is judged when it attacks a rule of the rulebook.

The search steers by a rollout's margin to a violation and counts an attack when the margin is below
0 (`RolloutResult.margin`, `RolloutResult.collided`). By default that margin is the collision rule's
(the minimum signed distance, or its at-fault variant), which every backend computes itself. Any
other rule is judged here, once per rollout and in one place (`AttackProblem`, which logs every
rollout, and the application for the attack's recorded rollout): its value is set as the rollout's
`verdict`, so the heuristic, the phases after it and the search methods attack that rule without
knowing which it is. Rules that compare the drive with the ground truth's (phantom braking,
progress) are judged against perfect perception's rollout, which every search rolls out first.
"""

from dataclasses import dataclass

from advperc_ros.core.rollout import RolloutConfig, RolloutResult
from advperc_ros.core.rules.base import Rule, RuleValue, evaluate
from advperc_ros.core.rules.inputs import rule_inputs
from advperc_ros.core.rules.registry import DEFAULT_RULEBOOK, RULES, Rulebook
from advperc_ros.core.scenario import Scenario

CONTACT_RULES = ("collision", "at_fault_collision")
"""The rules every backend judges itself, as the rollout runs: a contact ends the drive either way."""
DEFAULT_RULE = "collision"
AT_FAULT_RULE = "at_fault_collision"  # what imported recorded traffic is attacked under: it does not react to the ego


def contact_rule(at_fault_only: bool) -> str:
    """The contact rule a rollout config judges by (`rule.at_fault_only`)."""
    return AT_FAULT_RULE if at_fault_only else DEFAULT_RULE


@dataclass(frozen=True)
class AttackedRule:
    """A rule beyond the contact rules, judging the rollouts of one scenario run with `config` (the
    ego's footprint the rule reads) by the thresholds of `rulebook`; `verdict` is the rule's value on a rollout."""

    name: str
    scenario: Scenario
    config: RolloutConfig
    rulebook: Rulebook = DEFAULT_RULEBOOK

    def __post_init__(self) -> None:
        if self.name not in RULES or self.name in CONTACT_RULES:
            raise ValueError(f"rule '{self.name}' is not a rule the search judges apart from the rollout "
                             f"(rules: {', '.join(r for r in RULES if r not in CONTACT_RULES)})")

    @property
    def rule(self) -> Rule:
        return self.rulebook.rule(self.name)

    def value(self, result: RolloutResult, truth: RolloutResult | None) -> RuleValue:
        """The rule on `result`, against the ground truth's rollout `truth` (None: `result` is that rollout)."""
        inputs = rule_inputs(result, self.scenario, self.config)
        reference = inputs if truth is None else rule_inputs(truth, self.scenario, self.config)
        return evaluate(self.rule, inputs, reference)

    def judge(self, result: RolloutResult, truth: RolloutResult | None) -> RolloutResult:
        """`result` with its verdict set: the rule's value on it (see `value`)."""
        result.verdict = self.value(result, truth).value
        return result


def attacked_rule(name: str, scenario: Scenario, config: RolloutConfig,
                  rulebook: Rulebook = DEFAULT_RULEBOOK) -> AttackedRule | None:
    """The attacked rule `name` as the search judges it apart from the rollout, by `rulebook`'s thresholds; None
    for the contact rules, which the backends judge themselves (`RolloutConfig.at_fault_only` for the at-fault one;
    their parameters are fixed, as every backend judges them while the rollout runs)."""
    return None if name in CONTACT_RULES else AttackedRule(name, scenario, config, rulebook)
