"""What a rollout backend is, and the embedded one.

The search only needs `rollout(errors, record)` and to know which planner it attacks; `Stack` does
it in this process, `advperc_ros.graph.rollouts.GraphRollouts` through the node graph over DDS.
"""

from dataclasses import dataclass
from typing import Protocol

from advperc_ros.core.errors import PerceptionErrors
from advperc_ros.core.planners.registry import load_planner
from advperc_ros.core.rollout import RolloutResult, rollout
from advperc_ros.core.scenario import Scenario
from advperc_ros.core.tracker import Tracker
from advperc_ros.params import AttackParams, planning_context, rollout_config, tracker_config

EXTERNAL = "external"  # the `planner` of a report whose planner was a node of someone else's


@dataclass(frozen=True)
class AttackedPlanner:
    """Which planner the rollouts went through: the params' own, or an external node (its name as
    the middleware tells it, "" where it cannot), so the report names the system attacked."""

    name: str
    node: str | None = None


class Rollouts(Protocol):
    """What the search needs of a backend: one rollout of an error tensor; which planner it runs."""

    attacked_planner: AttackedPlanner

    def rollout(self, errors: PerceptionErrors, record: bool = False) -> RolloutResult: ...


class Stack:
    """The system under attack in this process, built from the params: tracker, planner, rollout."""

    def __init__(self, scenario: Scenario, params: AttackParams) -> None:
        values = params.flat()
        self.scenario = scenario
        self.config = rollout_config(values)
        self.tracker = Tracker(tracker_config(values))
        self.planner = load_planner(params.planner, planning_context(values, scenario), params.planner_params)
        self.attacked_planner = AttackedPlanner(params.planner)

    def rollout(self, errors: PerceptionErrors, record: bool = False) -> RolloutResult:
        return rollout(self.scenario, errors, self.tracker, self.planner, self.config, record=record)
