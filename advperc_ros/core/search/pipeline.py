"""The whole search: the paper's heuristic (Algorithm 1), the phantom obstacles when ghosts are on,
joint drops when no single agent's drop (nor phantom) collides and the approach phase when no drop
does, then the search method `config.method`
names (`registry.METHODS`: the paper's random search and refine phase, or the guided search).
What `advperc attack` and the orchestrator node run, whatever backend rolls out."""

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from advperc_ros.core.search import approach as approach_phase
from advperc_ros.core.search import books
from advperc_ros.core.search.approach import Approach
from advperc_ros.core.search.books import Estimate
from advperc_ros.core.search.config import SearchConfig, budget
from advperc_ros.core.search.heuristic import heuristic_search
from advperc_ros.core.search.joint import Joint, joint_drops
from advperc_ros.core.search.method import SearchMethod
from advperc_ros.core.search.phantom import phantom_modes
from advperc_ros.core.search.problem import AttackProblem, Evaluation
from advperc_ros.core.search.registry import search_method
from advperc_ros.exceptions import BudgetSpent


@dataclass(frozen=True)
class SearchResult:
    """What each part of a search found: the report shows the heuristic's and the best, the
    no-collision diagnosis the joint drops' and the approach phase's."""

    heuristic: Evaluation | None  # the best failure mode of Algorithm 1, the phantom obstacles or the joint
    # drops, else the approach phase's collision; None when none
    best: Evaluation | None  # the best adversarial evaluation of all phases: the attack reported
    joint: Joint | None = None  # the joint drops, when they ran to the end (no single drop collided)
    approach: Approach | None = None  # the approach phase, when it ran to the end (no drop collided)


def run_search(problem: AttackProblem, config: SearchConfig,
               on_estimate: Callable[[Estimate], None] | None = None) -> SearchResult:
    """All phases in order; the problem counts and logs every rollout and tracks the best. A search
    that reaches its budget ends there with the best attack so far. `on_estimate`: told after every
    rollout what the search still owes (`books.Estimate`), for a progress bar."""
    method = search_method(config)
    with books.kept(problem, config, method, on_estimate):
        return _phases(problem, config, method)


def _phases(problem: AttackProblem, config: SearchConfig, method: SearchMethod) -> SearchResult:
    problem.budget = budget(config, problem.scenario.agents.shape[1])
    heuristic = joint = approached = None
    num_agents = problem.scenario.agents.shape[1]
    try:
        found = heuristic_search(problem, config.heuristic_iterations, batched=method.batched_heuristic)
        probed, phantoms = phantom_modes(problem, found.truth, config.errors)
        modes = found.modes + phantoms
        problem.budget = budget(config, num_agents, joint=not modes)
        joint = None if phantoms else joint_drops(problem, found, config.heuristic_iterations, config.joint_max_agents)
        modes = modes or ([joint.mode] if joint is not None and joint.mode is not None else [])
        heuristic = max(modes, key=lambda mode: mode.metric) if modes else None
        rng = np.random.default_rng(config.seed)
        if heuristic is None and config.approach_steps > 0 and num_agents > 0:
            problem.budget = budget(config, num_agents, joint=True, approach=True)
            seen = [found.truth, *found.drops, *probed, *([joint.blind] if joint is not None else [])]
            approached = approach_phase.approach(problem, seen, rng, config.random, config.approach_steps,
                                                 config.approach_patience, config.errors)
            heuristic = approached.collision
        if heuristic is None:
            return SearchResult(None, None, joint, approached)
        problem.budget = method.tail_budget(len(problem.log), problem.budget)
        method.run(problem, heuristic, rng)
    except BudgetSpent:
        if heuristic is None:  # spent within the heuristic: its best failing rollout so far
            heuristic = problem.best
    return SearchResult(heuristic, problem.best, joint, approached)
