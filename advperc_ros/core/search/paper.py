"""The paper's method: after the heuristic's failure mode, random search (Algorithm 2) and the
refine phase beyond it, which re-detects the start of each dropped run of the best attack."""

from collections.abc import Sequence
from typing import ClassVar

import numpy as np

from advperc_ros.core.perception_errors.runs import dropped_runs
from advperc_ros.core.search import random_search as random_phase
from advperc_ros.core.search import refine
from advperc_ros.core.search.config import REFINED_RUNS, SearchConfig
from advperc_ros.core.search.problem import AttackProblem, Evaluation, LogRow, Phase, PhaseLabel
from advperc_ros.core.search.random_search import random_search
from advperc_ros.core.search.refine import refine_drops


class PaperMethod:
    """The paper's Algorithms 1 and 2, for reproducing it: the heuristic bisects each agent's drop
    before dropping the next, and the search keeps the paper's bound as its budget."""

    name = "paper"
    batched_heuristic = False
    phases: ClassVar[dict[Phase, PhaseLabel]] = {Phase.RANDOM: random_phase.LABEL, Phase.REFINE: refine.LABEL}

    def __init__(self, config: SearchConfig) -> None:
        self.config = config

    def tail_budget(self, used: int, budget: int) -> int:
        return budget

    def run(self, problem: AttackProblem, heuristic: Evaluation, rng: np.random.Generator) -> None:
        random_search(problem, heuristic, rng, self.config.random)
        if self.config.refine_iterations > 0:
            refine_drops(problem, problem.found, self.config.refine_iterations)

    def still_owed(self, logged: Sequence[LogRow], share: int, best: Evaluation | None) -> int:
        """The random steps left (a rollout each at most: a step none of whose proposals improves
        rolls none out), then refine's bisections of the best attack's dropped runs, `refine_iterations`
        rollouts a run. Until refine begins the random steps may split a run, so as many runs as the
        bound counts (`REFINED_RUNS`) at least; from then on the best attack's (refine shortens a run,
        never ends it)."""
        refined = sum(row.phase == Phase.REFINE for row in logged)
        runs = 0 if best is None else len(dropped_runs(best.errors.fn[: best.rollout.num_frames]))
        if refined:
            return self.config.refine_iterations * runs - refined
        return self.config.random.steps - len(logged) + self.config.refine_iterations * max(REFINED_RUNS, runs)
