"""Beyond the paper: refine the best attack by bisecting each dropped run's start once more.

The heuristic's bisection stops after 3 iterations (the paper's budget), so a dropped run usually
starts earlier than it needs to. This phase takes the best adversarial evaluation and, for each
run of false negatives, bisects how many of its first frames can be perceived perfectly again while
the rollout still collides. It costs `iterations` rollouts per run and only ever keeps failing
rollouts; under NDS, where hiding a car by displacement scores worse than dropping it, this is
where the remaining gains are.
"""

from advperc_ros.core.perception_errors.runs import dropped_runs
from advperc_ros.core.search.heuristic import bisect
from advperc_ros.core.search.problem import AttackProblem, Evaluation, Phase


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
