"""The whole search and its rollout budget: the paper's heuristic (Algorithm 1) and random search
(Algorithm 2), then the refine phase beyond the paper. What `advperc attack` and the orchestrator
node run, whatever backend rolls out."""

from dataclasses import dataclass

import numpy as np

from advperc_ros.core.search.heuristic import heuristic_search
from advperc_ros.core.search.problem import AttackProblem, Evaluation
from advperc_ros.core.search.random_search import RandomSearchConfig, random_search
from advperc_ros.core.search.refine import refine_drops


@dataclass(frozen=True)
class SearchConfig:
    heuristic_iterations: int = 3  # bisection iterations per bound (paper: 3)
    random: RandomSearchConfig = RandomSearchConfig()
    refine_iterations: int = 4  # 0: the paper's search only
    seed: int = 0  # of the random search


@dataclass(frozen=True)
class SearchResult:
    heuristic: Evaluation | None  # the best failure mode of Algorithm 1; None when no agent is influential
    random: Evaluation | None  # Algorithm 2's e*: its last accepted evaluation
    refined: Evaluation | None  # the refine phase's attack
    best: Evaluation | None  # the best adversarial evaluation of all phases: the attack reported


def budget(config: SearchConfig, num_agents: int) -> int:
    """Rollouts the search runs at most: ground truth, per agent a drop and two bisections, the
    random steps (each rolls out one proposal, or none when no proposal improves) and refine's two
    bounds per iteration."""
    return 1 + num_agents * (1 + 2 * config.heuristic_iterations) + config.random.steps + 2 * config.refine_iterations


def run_search(problem: AttackProblem, config: SearchConfig) -> SearchResult:
    """All phases in order; the problem counts and logs every rollout and tracks the best."""
    modes = heuristic_search(problem, config.heuristic_iterations)
    heuristic = max(modes, key=lambda mode: mode.metric) if modes else None
    if heuristic is None:
        return SearchResult(None, None, None, None)
    searched = random_search(problem, heuristic, np.random.default_rng(config.seed), config.random)
    refined = refine_drops(problem, problem.best, config.refine_iterations) if config.refine_iterations > 0 else None
    return SearchResult(heuristic, searched, refined, problem.best)
