"""What a search method is: the phases that follow the heuristic's failure mode, as a plug-in.

Every method shares the start of the search (`pipeline.run_search`): ground truth, the paper's
heuristic (Algorithm 1), the joint drops and the approach phase when no drop collides. A method
is what comes after, from the failure mode found to the attack reported; the paper's (random
search and refine, `paper.PaperMethod`) and the guided search (`guided.GuidedMethod`) are two.

The progress bar, the plots and the report ask a method what they need (how to show its phases,
what it still owes) rather than branching on its name, so adding one is one module and one line of
`registry.METHODS`. This module is the interface only: it imports no method, so any module may
import it (as nuPlan's AbstractPlanner).
"""

from collections.abc import Mapping, Sequence
from typing import ClassVar, Protocol

import numpy as np

from advperc_ros.core.search.config import SearchConfig
from advperc_ros.core.search.problem import AttackProblem, Evaluation, LogRow, Phase, PhaseLabel


class SearchMethod(Protocol):
    """A search method: built with the search's config, it runs once the heuristic found a failure mode."""

    name: ClassVar[str]  # as `search.method` and `advperc attack --method` name it
    batched_heuristic: ClassVar[bool]  # the heuristic drops every agent before bisecting any (rollouts at once)
    phases: ClassVar[Mapping[Phase, PhaseLabel]]  # the phases it logs rollouts under, in order, and how to show them

    def __init__(self, config: SearchConfig) -> None: ...

    def tail_budget(self, used: int, budget: int) -> int:
        """The rollouts the search ends at once this method starts, `used` having been run to find
        the failure mode and `budget` being the search's budget so far (keep it, or spend less)."""

    def run(self, problem: AttackProblem, heuristic: Evaluation, rng: np.random.Generator) -> None:
        """Improve on the failure mode `heuristic` through `problem` (which counts, logs, enforces
        the budget and keeps the best) with the search's random draws `rng`; the attack reported is
        the problem's best. It may end by running out of budget (`BudgetSpent`)."""

    def still_owed(self, logged: Sequence[LogRow], share: int, best: Evaluation | None) -> int:
        """Rollouts it may still run, at most, having logged `logged` (the rows of its phases, none
        before it began) of the `share` of the budget it has (`tail_budget` less the rollouts run
        before it), `best` being the best attack so far (None before a failure mode is found); the
        search's estimate of the rollouts to come (`books.Estimate`) counts it from the first rollout."""
