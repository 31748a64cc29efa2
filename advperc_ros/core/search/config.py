"""What a search is configured with, and the rollout bound of the paper's search that budgets derive from.

The configs here are built from the params tree by `advperc_ros.configs` (their defaults are the
schema's, a test checks it); every search method takes the one `SearchConfig`, so a new method
adds its own section here only if it has parameters of its own.
"""

from dataclasses import dataclass

from advperc_ros.core.perception_errors import ErrorSpace
from advperc_ros.core.search import approach as approach_phase
from advperc_ros.core.search import phantom
from advperc_ros.core.search.joint import worst_case
from advperc_ros.core.search.random_search import RandomSearchConfig


@dataclass(frozen=True)
class GuidedConfig:
    """The guided method's rounds: how many candidates each scores exactly, how many it rolls out."""

    candidates: int = 400  # scored per round
    batch: int = 2  # rolled out per round
    random: RandomSearchConfig = RandomSearchConfig()  # the paper's proposal: max offset, yaw noise


@dataclass(frozen=True)
class SearchConfig:
    """Every phase's settings and which method follows the heuristic: one value that fixes, with the
    scenario, the backend's rollouts and the seed, the whole search (so a checkpoint can resume it)."""

    heuristic_iterations: int = 3  # bisection iterations per bound (paper: 3)
    joint_max_agents: int = 8  # agents the joint drops' reduction keeps at most; 0: no joint drops
    approach_steps: int = 120  # rollouts of the approach phase at most, when no drop collides; 0: no approach phase
    approach_patience: int = 30  # rollouts in a row that bring the ego no nearer before the approach phase gives up
    random: RandomSearchConfig = RandomSearchConfig()
    refine_iterations: int = 4  # 0: the paper's search only
    seed: int = 0  # of the search's random draws
    method: str = "guided"  # guided: heuristic, guided search; paper: heuristic, random search, refine
    guided: GuidedConfig = GuidedConfig()
    errors: ErrorSpace = ErrorSpace()  # the kinds of error the search may make, and their bounds
    # rollouts at most; 0: `bound`, what the search can use at most (a method may spend less: `SearchMethod.tail_budget`)
    budget: int = 0


def bound(config: SearchConfig, num_agents: int, joint: bool = False, approach: bool = False) -> int:
    """Rollouts the paper's search may run: ground truth, per agent a drop and two bisections, and
    `after_failure_bound`; the phantom obstacles when ghosts are on; and the joint drops' worst case
    when they run (`joint`: no single drop collided) and the approach phase's when it runs
    (`approach`: no drop collided), so a search of the paper's kinds where a drop collides keeps the
    paper's bound."""
    joint_worst = worst_case(config.joint_max_agents, num_agents) if joint else 0
    approach_worst = approach_phase.worst_case(config.approach_steps, num_agents) if approach else 0
    return (1 + num_agents * (1 + 2 * config.heuristic_iterations) + phantom.worst_case(config.errors) + joint_worst
            + approach_worst + after_failure_bound(config))


REFINED_RUNS = 2  # dropped runs of the best attack whose bisections `bound` counts (refine_iterations rollouts a run)


def after_failure_bound(config: SearchConfig) -> int:
    """The share of `bound` that follows the failure mode: the random steps (one rollout each at
    most) and refine's bisections of `REFINED_RUNS` dropped runs (`refine_iterations` rollouts a run)."""
    return config.random.steps + REFINED_RUNS * config.refine_iterations


def budget(config: SearchConfig, num_agents: int, joint: bool = False, approach: bool = False) -> int:
    """Rollouts the search runs at most: `config.budget`, or `bound` when 0."""
    return config.budget or bound(config, num_agents, joint, approach)


def largest_budget(config: SearchConfig, num_agents: int) -> int:
    """Rollouts the search runs at most, whichever phases it comes to: what its checkpoint may hold."""
    return budget(config, num_agents, joint=True, approach=True)


def smallest_budget(num_agents: int) -> int:
    """The fewest rollouts a `search.budget` may give: the ground truth and one drop of each agent (the
    guided method's first batch, which a smaller budget does not fit; the paper's tries every agent once)."""
    return 1 + num_agents
