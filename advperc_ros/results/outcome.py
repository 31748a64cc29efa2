"""What an attack comes to: the search's result and log, and the best attack recorded; what the
results folder, its pictures and the report are written from."""

from dataclasses import dataclass, field
from functools import cached_property

from advperc_ros.core.rollout import RolloutConfig, RolloutResult
from advperc_ros.core.rules.base import RuleValue
from advperc_ros.core.rules.inputs import RuleInputs, rule_inputs
from advperc_ros.core.rules.registry import DEFAULT_RULEBOOK, Rulebook, evaluate_rulebook
from advperc_ros.core.rules.verdict import CONTACT_RULES, contact_rule
from advperc_ros.core.scenario import Scenario
from advperc_ros.core.search.approach import Approach
from advperc_ros.core.search.joint import Joint
from advperc_ros.core.search.problem import Evaluation, LogRow
from advperc_ros.params import AttackParams

REPRODUCTION_TOLERANCE = 1e-9  # m: the graph's own tolerance against the embedded rollout (docs/graph.md)


@dataclass(frozen=True)
class AttackOutcome:
    """Everything one attack produced, before anything is written: the report, the bag and the plots
    are all made from it, so what a user reads in each cannot disagree. The rulebook's verdicts on its
    rollouts are computed here once (`attack_rules`, `ground_truth_rules`) for all of them."""

    scenario: Scenario
    params: AttackParams  # as run: `planner` is EXTERNAL when an external node planned
    heuristic_best: Evaluation | None  # None when no agent is influential
    best: Evaluation | None  # best adversarial evaluation of the whole search
    recorded: RolloutResult | None  # the best attack rolled out again with tracks and plans kept
    log: list[LogRow]
    wall_time_s: float
    planner_node: str | None = None  # the external planner node, when one planned
    tracker_node: str | None = None  # the external tracker node, when one tracked
    planner_version: str | None = None  # what the external planner node announced as its version, if it did
    # when no single drop collided: the joint drops, with the ego's rollout with every vehicle hidden
    # (the most any drop can take away) and the agents of the failure mode they found, if any
    joint: Joint | None = None
    # when no drop collided: the approach phase, with the closest margin it reached
    approach: Approach | None = None
    ground_truth: RolloutResult | None = None  # perfect perception's rollout (None: the search ended before it)
    # what the rollouts ran with: the ego's footprint, which the rules read
    rollout_config: RolloutConfig = field(default_factory=RolloutConfig)
    rulebook: Rulebook = DEFAULT_RULEBOOK  # the thresholds its rules were judged by (`rule.<rule>.<parameter>`)

    @property
    def attack(self) -> Evaluation:
        """`best`, where only an attack found is written (its errors, its bag, its pictures)."""
        if self.best is None:
            raise ValueError(f"{self.scenario.name}: no attack was found")
        return self.best

    @property
    def reproduced(self) -> bool | None:
        """Whether the attack, rolled out again at the end (`recorded`), gave the verdict, the minimum
        signed distance and the attacked rule's value (when not a contact rule) the search saw (within
        REPRODUCTION_TOLERANCE); None without an
        attack. A planner or node whose output depends on more than its reset and its inputs (state
        kept across resets, wall-clock timing) makes the search's attack a claim nobody can replay:
        this is where that shows."""
        if self.best is None or self.recorded is None:
            return None
        found, again = self.best.rollout, self.recorded
        same_rule = found.verdict is None or (again.verdict is not None
                                              and abs(found.verdict - again.verdict) <= REPRODUCTION_TOLERANCE)
        return bool(found.collided == again.collided and found.inconclusive == again.inconclusive and same_rule
                    and abs(found.min_signed_distance - again.min_signed_distance) <= REPRODUCTION_TOLERANCE)

    @property
    def attack_rollout(self) -> RolloutResult:
        """`recorded`, the attack rolled out again with tracks and plans: an outcome with an attack has one."""
        if self.recorded is None:
            raise ValueError(f"{self.scenario.name}: no attack rollout recorded")
        return self.recorded

    @property
    def attacked_rule(self) -> str:
        """The rule the search attacked, as the rulebook names it: `rule.name`, or for a contact rule the one the
        rollouts were judged by (`rule.at_fault_only` makes `collision` the at-fault one)."""
        name = self.params.rule.name
        return contact_rule(self.rollout_config.at_fault_only) if name in CONTACT_RULES else name

    @cached_property
    def _truth_inputs(self) -> RuleInputs | None:
        if self.ground_truth is None:
            return None
        return rule_inputs(self.ground_truth, self.scenario, self.rollout_config)

    def _judged(self, inputs: RuleInputs, truth: RuleInputs) -> dict[str, RuleValue]:
        """Every rule of the rulebook, by its thresholds (`rulebook`), on `inputs` against the ground truth's
        rollout `truth`: the one place an outcome's rollouts are judged by it."""
        return evaluate_rulebook(inputs, truth, self.rulebook)

    @cached_property
    def ground_truth_rules(self) -> dict[str, RuleValue] | None:
        """Every rule of the rulebook on perfect perception's rollout (its own reference); None if the search
        ended before it."""
        truth = self._truth_inputs
        return None if truth is None else self._judged(truth, truth)

    @cached_property
    def attack_rules(self) -> dict[str, RuleValue] | None:
        """Every rule of the rulebook on the attack's recorded rollout against the ground truth's, per frame: what
        report.json's `rules`, the bag's /rules/<name> topics and the plots show; None without an attack recorded
        or a ground-truth rollout."""
        truth = self._truth_inputs
        if self.recorded is None or truth is None:
            return None
        return self._judged(rule_inputs(self.recorded, self.scenario, self.rollout_config), truth)

    @property
    def attacked_rule_value(self) -> RuleValue | None:
        """The attacked rule on the attack's recorded rollout (`attack_rules`); None where the rulebook did not judge it."""
        return None if self.attack_rules is None else self.attack_rules[self.attacked_rule]

    @property
    def violation_frame(self) -> int:
        """The frame the review surfaces look at (the layout's camera, the plots' mark): the attacked rule's first
        violating frame on the attack's rollout; its closest approach (the collision) where the rulebook did not
        judge it (no ground-truth rollout) or finds it unbroken."""
        judged = self.attacked_rule_value
        frame = None if judged is None else judged.first_violation
        return self.attack_rollout.closest_approach()[0] if frame is None else frame
