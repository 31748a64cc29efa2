"""What a search method is: the phases that follow the heuristic's failure mode, as a plug-in.

Every method shares the start of the search (`pipeline.run_search`): ground truth, the paper's
heuristic (Algorithm 1), the joint drops and the approach phase when no drop collides. A method
is what comes after, from the failure mode found to the attack reported; the paper's (random
search and refine, `paper.PaperMethod`) and the guided search (`guided.GuidedMethod`) are two.

The progress bar, the plots and the report ask a method what they need (its phases' names, what it
still owes) rather than branching on its name, so adding one is one module and one line of
`registry.METHODS`. This module is the interface only: it imports no method, so any module may
import it (as nuPlan's AbstractPlanner).
"""

from collections.abc import Mapping
from dataclasses import dataclass
from typing import ClassVar, Protocol

import numpy as np

from advperc_ros.core.search.config import SearchConfig
from advperc_ros.core.search.problem import AttackProblem, Evaluation, Phase


@dataclass(frozen=True)
class Progress:
    """What a progress bar has counted of a search, for a method to tell what it still owes."""

    run: int  # rollouts run before the one being counted
    began: int | None  # rollouts run before the method's own phases began; None: not yet begun
    random: int  # rollouts of the random-search phase so far
    refined: int  # rollouts of the refine phase so far
    refine_runs: int  # dropped runs of the best attack so far, which a refine phase would bisect


class SearchMethod(Protocol):
    """A search method: built with the search's config, it runs once the heuristic found a failure mode."""

    name: ClassVar[str]  # as `search.method` and `advperc attack --method` name it
    batched_heuristic: ClassVar[bool]  # the heuristic drops every agent before bisecting any (rollouts at once)
    phases: ClassVar[Mapping[Phase, str]]  # the phases it logs rollouts under, in order, and what to call them

    def __init__(self, config: SearchConfig) -> None: ...

    def tail_budget(self, used: int, budget: int) -> int:
        """The rollouts the search ends at once this method starts, `used` having been run to find
        the failure mode and `budget` being the search's budget so far (keep it, or spend less)."""

    def run(self, problem: AttackProblem, heuristic: Evaluation, rng: np.random.Generator) -> None:
        """Improve on the failure mode `heuristic` through `problem` (which counts, logs, enforces
        the budget and keeps the best) with the search's random draws `rng`; the attack reported is
        the problem's best. It may end by running out of budget (`BudgetSpent`)."""

    def still_owed(self, phase: Phase | None, progress: Progress) -> int:
        """Rollouts its phases may still run, at most, in `phase` (one of `phases`, or None before
        they began); the progress bar's total comes from it."""
