"""The whole search and its rollout budget: the paper's heuristic (Algorithm 1), with joint drops when
no single agent's drop collides and the approach phase when no drop does, then either the paper's random search (Algorithm 2) and the refine
phase beyond the paper (method `paper`), or the guided search (method `guided`). What `advperc
attack` and the orchestrator node run, whatever backend rolls out."""

from dataclasses import dataclass

import numpy as np

from advperc_ros.core.search import approach as approach_phase
from advperc_ros.core.search.approach import Approach
from advperc_ros.core.search.guided import GuidedConfig, guided_search
from advperc_ros.core.search.heuristic import heuristic_search
from advperc_ros.core.search.joint import Joint, joint_drops, worst_case
from advperc_ros.core.search.problem import AttackProblem, BudgetSpent, Evaluation
from advperc_ros.core.search.random_search import RandomSearchConfig, random_search
from advperc_ros.core.search.refine import refine_drops


# paper: the paper's Algorithms 1 and 2 and the refine phase; guided: Algorithm 1, then the guided search
METHODS = ("paper", "guided")


@dataclass(frozen=True)
class SearchConfig:
    heuristic_iterations: int = 3  # bisection iterations per bound (paper: 3)
    joint_max_agents: int = 8  # agents the joint drops' reduction keeps at most; 0: no joint drops
    approach_steps: int = 120  # rollouts of the approach phase at most, when no drop collides; 0: no approach phase
    approach_patience: int = 30  # rollouts in a row that bring the ego no nearer before the approach phase gives up
    random: RandomSearchConfig = RandomSearchConfig()
    refine_iterations: int = 4  # 0: the paper's search only
    seed: int = 0  # of the search's random draws
    method: str = "guided"  # guided: heuristic, guided search; paper: heuristic, random search, refine
    guided: GuidedConfig = GuidedConfig()
    budget: int = 0  # rollouts at most; 0: `bound`, what the search can use at most (guided: `guided_budget`)


@dataclass(frozen=True)
class SearchResult:
    heuristic: Evaluation | None  # the best failure mode of Algorithm 1 or the joint drops, else the approach
    # phase's collision; None when none
    random: Evaluation | None  # Algorithm 2's e*: its last accepted evaluation (paper method)
    refined: Evaluation | None  # the refine phase's attack (paper method)
    best: Evaluation | None  # the best adversarial evaluation of all phases: the attack reported
    joint: Joint | None = None  # the joint drops, when they ran to the end (no single drop collided)
    approach: Approach | None = None  # the approach phase, when it ran to the end (no drop collided)


def bound(config: SearchConfig, num_agents: int, joint: bool = False, approach: bool = False) -> int:
    """Rollouts the paper's search may run: ground truth, per agent a drop and two bisections, and
    `after_failure_bound`; and the joint drops' worst case when they run (`joint`: no single drop
    collided) and the approach phase's when it runs (`approach`: no drop collided), so a search where
    a drop collides keeps the paper's bound."""
    joint_worst = worst_case(config.joint_max_agents, num_agents) if joint else 0
    approach_worst = approach_phase.worst_case(config.approach_steps, num_agents) if approach else 0
    return (1 + num_agents * (1 + 2 * config.heuristic_iterations) + joint_worst + approach_worst
            + after_failure_bound(config))


def after_failure_bound(config: SearchConfig) -> int:
    """The share of `bound` that follows the failure mode: the random steps (one rollout each at
    most) and refine's bisections of two dropped runs (`refine_iterations` rollouts a run)."""
    return config.random.steps + 2 * config.refine_iterations


def budget(config: SearchConfig, num_agents: int, joint: bool = False, approach: bool = False) -> int:
    """Rollouts the search runs at most: `config.budget`, or `bound` when 0."""
    return config.budget or bound(config, num_agents, joint, approach)


def guided_budget(config: SearchConfig, used: int) -> int:
    """Rollouts the guided search ends at, `used` having been run to find its failure mode:
    `config.budget`, or when 0 the share of `bound` that follows the failure mode
    (`after_failure_bound`). `bound` itself also counts bisections of agents whose drop did not
    collide, which a recording's dozens of cars make several times what the paper's search spends."""
    return config.budget or used + after_failure_bound(config)


def run_search(problem: AttackProblem, config: SearchConfig) -> SearchResult:
    """All phases in order; the problem counts and logs every rollout and tracks the best. A search
    that reaches its budget ends there with the best attack so far."""
    problem.budget = budget(config, problem.scenario.agents.shape[1])
    heuristic = searched = refined = joint = approached = None
    num_agents = problem.scenario.agents.shape[1]
    try:
        guided = config.method == "guided"
        found = heuristic_search(problem, config.heuristic_iterations, batched=guided)
        problem.budget = budget(config, num_agents, joint=not found.modes)
        joint = joint_drops(problem, found, config.heuristic_iterations, config.joint_max_agents)
        modes = found.modes or ([joint.mode] if joint is not None and joint.mode is not None else [])
        heuristic = max(modes, key=lambda mode: mode.metric) if modes else None
        rng = np.random.default_rng(config.seed)
        if heuristic is None and config.approach_steps > 0 and num_agents > 0:
            problem.budget = budget(config, num_agents, joint=True, approach=True)
            seen = [found.truth, *found.drops, *([joint.blind] if joint is not None else [])]
            approached = approach_phase.approach(problem, seen, rng, config.random, config.approach_steps,
                                                 config.approach_patience)
            heuristic = approached.collision
        if heuristic is None:
            return SearchResult(None, None, None, None, joint, approached)
        if guided:
            problem.budget = guided_budget(config, len(problem.log))
            guided_search(problem, rng, config.guided, problem.budget, config.refine_iterations)
        else:
            searched = random_search(problem, heuristic, rng, config.random)
            if config.refine_iterations > 0:
                refined = refine_drops(problem, problem.best, config.refine_iterations)
    except BudgetSpent:
        if heuristic is None:  # spent within the heuristic: its best failing rollout so far
            heuristic = problem.best
    return SearchResult(heuristic, searched, refined, problem.best, joint, approached)
