"""What a rollout backend is: the one thing the search needs of the system under attack.

The search only needs `rollout(errors, record)` and to know which planner it attacks; the
embedded backend (`embedded.Stack`) does it in this process, the graph backend
(`graph.rollouts.GraphRollouts`) through the node graph over DDS, and `resumed.ResumedRollouts`
answers from a checkpoint what an interrupted attack already ran.
"""

from dataclasses import dataclass
from typing import Protocol

from advperc_ros.core.perception_errors import PerceptionErrors
from advperc_ros.core.rollout import RolloutResult

EXTERNAL = "external"  # the `planner` of a report whose planner was a node of someone else's


@dataclass(frozen=True)
class AttackedPlanner:
    """Which planner the rollouts went through: the params' own, or an external node (its name as
    the middleware tells it, "" where it cannot), so the report names the system attacked; and the
    tracker node whose tracks it planned on, when that was a team's own (None: ours)."""

    name: str
    node: str | None = None
    tracker_node: str | None = None
    version: str | None = None  # what the external planner node announced of itself on /attack/nodes, if it did


class Rollouts(Protocol):
    """What the search needs of a backend: one rollout of an error tensor; which planner it runs."""

    @property
    def attacked_planner(self) -> AttackedPlanner: ...

    def rollout(self, errors: PerceptionErrors, record: bool = False) -> RolloutResult: ...
