"""Beyond the paper: refine the best attack by bisecting each dropped run's start once more.

The heuristic's bisection stops after 3 iterations (the paper's budget), so a dropped run usually
starts earlier than it needs to. This phase takes the best adversarial evaluation and, for each
run of false negatives, bisects how many of its first frames can be perceived perfectly again while
the rollout still collides. It costs `iterations` rollouts per run and only ever keeps failing
rollouts; under NDS, where hiding a car by displacement scores worse than dropping it, this is
where the remaining gains are.
"""

import numpy as np

from advperc_ros.core.perception_errors import PerceptionErrors
from advperc_ros.core.search.heuristic import bisect
from advperc_ros.core.search.problem import AttackProblem, Evaluation, Phase


def dropped_runs(fn: np.ndarray) -> list[tuple[int, int, int]]:
    """(slot, first, last) of every run of consecutive dropped frames, by slot then time."""
    runs = []
    for j in np.flatnonzero(fn.any(axis=0)):
        edges = np.diff(np.concatenate([[0], fn[:, j].astype(np.int8), [0]]))
        runs += [(int(j), int(a), int(b) - 1) for a, b in zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1))]
    return runs


def run_edge(first: int, last: int, rng: np.random.Generator) -> tuple[int, int]:
    """(a, b): the first or last k frames of the run first..last, k uniform up to half the run: the
    frames a move towards no error takes back."""
    k = int(rng.integers(1, max(1, (last - first + 1) // 2) + 1))
    return (first, first + k - 1) if rng.integers(2) else (last - k + 1, last)


def attacked_runs(errors: PerceptionErrors, frames: int) -> list[tuple[int, int, int]]:
    """(slot, first, last) of every run of attacked object-frames (`PerceptionErrors.attacked`)."""
    return dropped_runs(errors.attacked()[:frames])


def refine_drops(problem: AttackProblem, best: Evaluation, iterations: int = 4) -> Evaluation:
    """The refined attack (the problem tracks the best metric, as in the other phases)."""
    agents = problem.scenario.agents
    for j, first, last in dropped_runs(best.errors.fn[: best.rollout.num_frames]):
        agent = int(agents.ids[first, j])
        base = best.errors

        def restored(count: int, base=base, j=j, first=first):
            out = base.copy()
            out.perceive_perfectly(first, first + count - 1, j)
            return out

        count, failing = bisect(problem, 0, last - first + 1, restored, Phase.REFINE, agent, iterations, best)
        if count > 0 and failing.metric > best.metric:
            best = failing
    return best
