"""Beyond the paper: joint drops, for when no single agent's whole-track drop breaks the rule.

Algorithm 1 drops one agent at a time. An ego that would stop for either of two cars ahead is
never made to collide by hiding one of them, only by hiding both. So when no single drop collides,
every agent is dropped at once (the `blind` rollout, which also tells a null result whether missed
detections can matter at all); if that collides, the set is reduced to a small one that still does,
and each of its agents' segments is bisected as Algorithm 1 does, one agent at a time with the
others still dropped: one failure mode that drops several agents.

The reduction orders the agents by relevance, the closest approach to the ego in the blind or the
ground-truth rollout (no rollout needed), and bisects over prefixes of that order for the first
agent whose addition makes the drop collide. That agent is kept, and the bisection repeats among the
agents before it with the kept ones dropped too, until the kept ones collide on their own. A kept
agent was needed where it was found: dropping the rest of the final set, and more, did not collide;
so if hiding more never helps the ego, no agent of the set can be left out. Each kept agent costs at
most one rollout of the kept set and ceil(log2 N) of the bisection; a set rolled out before
(nothing, one agent, every agent) is not rolled out again.
"""

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from advperc_ros.core.search import heuristic
from advperc_ros.core.search.heuristic import Heuristic, dropping, narrow
from advperc_ros.core.search.problem import AttackProblem, Evaluation, LogRow, Phase

PHASES = {Phase.JOINT: heuristic.LABEL}  # Algorithm 1 for several agents at once, shown as it


@dataclass(frozen=True)
class Joint:
    """What the joint drops found, when no single agent's drop collided: whether hiding everyone
    collides (`blind`) and, if so, the few agents whose joint drop does (the failure mode)."""

    blind: Evaluation  # every agent dropped at once
    agents: tuple[int, ...]  # ids of the agents the failure mode drops; () when the blind rollout did not collide
    mode: Evaluation | None  # their segments bisected; None when the blind rollout did not collide


def worst_case(max_agents: int, num_agents: int) -> int:
    """Rollouts the joint phase adds to Algorithm 1's at most: the blind rollout; per agent kept, a
    bisection over prefixes (ceil(log2 N)); and a rollout of each kept set from two agents on (one kept
    agent is a single drop, rolled out already): 1 + M ceil(log2 N) + M - 1. The bisections of the
    set's segments, 2 x iterations per agent, are not added: they stand in for the single agents'
    bisections, none of which ran."""
    if max_agents == 0 or num_agents < 2:
        return 0
    return max_agents * (1 + math.ceil(math.log2(num_agents)))


def still_owed(logged: Sequence[LogRow], max_agents: int, num_agents: int, iterations: int) -> int:
    """Rollouts `joint_drops` may still run, at most, having logged `logged` (the blind rollout
    first): none once the blind rollout did not collide; else what the reduction may (`worst_case`
    of the agents it may keep, `max_agents` or all; its rollouts are of no one agent) until the first
    bisection of the set's segments, and those bisections, 2 x `iterations` an agent of the set (more
    agents only when the reduction stopped at `max_agents`)."""
    if logged and not logged[0].collided:
        return 0
    kept = min(max_agents, num_agents)
    narrowed = sum(row.agent != -1 for row in logged)
    reduction = 0 if narrowed else max(0, worst_case(kept, num_agents) - len(logged))
    return reduction + max(0, 2 * iterations * kept - narrowed)


def relevance(truth: Evaluation, blind: Evaluation) -> list[int]:
    """Slots by their closest approach to the ego in either rollout, nearest first (ties by slot)."""
    closest = np.minimum(blind.rollout.distances.min(axis=0, initial=np.inf),
                         truth.rollout.distances.min(axis=0, initial=np.inf))
    return [int(j) for j in np.argsort(closest, kind="stable")]


def whole_drops(problem: AttackProblem, known: dict[frozenset[int], Evaluation], slots) -> Evaluation:
    """The rollout of the slots' whole tracks dropped together, rolled out unless `known` holds it."""
    key = frozenset(slots)
    if key not in known:
        shape = problem.scenario.agents.shape
        known[key] = problem.evaluate(dropping(shape, dict.fromkeys(sorted(key), (0, shape[0] - 1))), Phase.JOINT)
    return known[key]


def reduce(problem: AttackProblem, known: dict[frozenset[int], Evaluation], order: list[int],
           max_agents: int) -> tuple[int, ...]:
    """Slots whose joint whole-track drop collides, those kept in the order found; `known` holds the sets
    rolled out before, every slot's among them (colliding). Past `max_agents` kept, the set that
    last collided: the kept ones and every candidate left."""
    def collides(slots: list[int]) -> bool:
        return whole_drops(problem, known, slots).adversarial

    kept: list[int] = []
    candidates = order
    while not collides(kept):
        if len(kept) == max_agents:
            return (*kept, *candidates)
        fails, passes = len(candidates), 0  # kept + candidates[:fails] collides, kept + candidates[:passes] does not
        while fails - passes > 1:
            mid = (fails + passes) // 2
            if collides(kept + candidates[:mid]):
                fails = mid
            else:
                passes = mid
        kept.append(candidates[fails - 1])
        candidates = candidates[: fails - 1]
    return tuple(kept)


def joint_drops(problem: AttackProblem, heuristic: Heuristic, iterations: int, max_agents: int) -> Joint | None:
    """The joint phase after Algorithm 1: None when it does not run (an agent is influential, no agent,
    or `max_agents` 0)."""
    num_frames, num_agents = problem.scenario.agents.shape
    if heuristic.modes or num_agents == 0 or max_agents == 0:
        return None
    known = {frozenset(): heuristic.truth, **{frozenset([j]): drop for j, drop in enumerate(heuristic.drops)}}
    blind = whole_drops(problem, known, range(num_agents))
    if not blind.adversarial:
        return Joint(blind, (), None)
    order = relevance(heuristic.truth, blind)
    slots = sorted(reduce(problem, known, order, max_agents), key=order.index)
    segments, failing = dict.fromkeys(slots, (0, num_frames - 1)), known[frozenset(slots)]
    for j in slots:
        segments, failing = narrow(problem, segments, j, iterations, failing, (Phase.JOINT, Phase.JOINT))
    return Joint(blind, tuple(problem.scenario.agent_id(j) for j in slots), failing)
