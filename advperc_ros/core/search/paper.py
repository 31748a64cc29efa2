"""The paper's method: after the heuristic's failure mode, random search (Algorithm 2) and the
refine phase beyond it, which re-detects the start of each dropped run of the best attack."""

from typing import ClassVar

import numpy as np

from advperc_ros.core.search.config import SearchConfig
from advperc_ros.core.search.method import Progress
from advperc_ros.core.search.problem import AttackProblem, Evaluation, Phase
from advperc_ros.core.search.random_search import random_search
from advperc_ros.core.search.refine import refine_drops


class PaperMethod:
    """The paper's Algorithms 1 and 2, for reproducing it: the heuristic bisects each agent's drop
    before dropping the next, and the search keeps the paper's bound as its budget."""

    name = "paper"
    batched_heuristic = False
    phases: ClassVar[dict[Phase, str]] = {Phase.RANDOM: "random search", Phase.REFINE: "refine"}

    def __init__(self, config: SearchConfig) -> None:
        self.config = config

    def tail_budget(self, used: int, budget: int) -> int:
        return budget

    def run(self, problem: AttackProblem, heuristic: Evaluation, rng: np.random.Generator) -> None:
        random_search(problem, heuristic, rng, self.config.random)
        if self.config.refine_iterations > 0:
            refine_drops(problem, problem.found, self.config.refine_iterations)

    def still_owed(self, phase: Phase | None, progress: Progress) -> int:
        """The random steps left (one rollout each at most), then refine's bisections of the best
        attack's dropped runs (`refine_iterations` rollouts a run)."""
        refine = self.config.refine_iterations * progress.refine_runs
        if phase == Phase.REFINE:
            return max(0, refine - progress.refined)
        return max(0, self.config.random.steps - progress.random) + refine
