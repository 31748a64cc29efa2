"""Algorithm 1 of the paper: find influential agents, then bisect their dropped segment.

For each agent, drop its whole track; if that breaks the rule, bisect the latest start of a drop
that runs to the end, then the earliest end of a drop from that start. Bisection moves a bound
only on a definite verdict: an inconclusive rollout ends that bisection where it stands.
"""

from collections.abc import Callable

from advperc_ros.core.errors import PerceptionErrors
from advperc_ros.core.search.problem import AttackProblem, Evaluation, GroundTruthFails, Phase


def bisect(
    problem: AttackProblem,
    fails: int,
    passes: int,
    errors_at: Callable[[int], PerceptionErrors],
    phase: Phase,
    agent: int,
    iterations: int,
    failing: Evaluation,
) -> tuple[int, Evaluation]:
    """Move the failing bound towards the passing one; returns it with its evaluation."""
    for _ in range(iterations):
        mid = (fails + passes) // 2
        if mid in (fails, passes):
            break
        trial = problem.evaluate(errors_at(mid), phase, agent)
        if trial.rollout.inconclusive:
            break
        if trial.adversarial:
            fails, failing = mid, trial
        else:
            passes = mid
    return fails, failing


def check_ground_truth(truth: Evaluation) -> None:
    """Refuse to attack a stack that breaks the rule with perfect perception."""
    if truth.rollout.inconclusive:
        raise GroundTruthFails(f"the ground-truth rollout is inconclusive: {truth.rollout.inconclusive}")
    if truth.adversarial:
        raise GroundTruthFails(
            f"the planner already collides with perfect perception "
            f"(min signed distance {truth.rollout.min_signed_distance:.3f} m); nothing to attack"
        )


def heuristic_search(problem: AttackProblem, iterations: int = 3, batched: bool = False) -> list[Evaluation]:
    """Failure modes, one per influential agent, each the narrowest failing drop found. In the
    paper's order (each agent's drop, then its bisections), or `batched` (the guided method): the
    ground truth and every agent's drop roll out as one batch, which a backend may run at once;
    the same rollouts and failure modes either way."""
    scenario = problem.scenario
    num_frames, num_agents = scenario.agents.shape
    none = PerceptionErrors.none(num_frames, num_agents)
    agents = [int(scenario.agents.ids[scenario.agents.valid[:, j].argmax(), j]) for j in range(num_agents)]
    drops = [(none.with_drop(j, 0, num_frames - 1), Phase.HEURISTIC_DROP, agents[j]) for j in range(num_agents)]
    upfront = problem.evaluate_many([(none, Phase.GROUND_TRUTH, -1), *drops]) if batched else None
    check_ground_truth(upfront[0] if upfront else problem.evaluate(none, Phase.GROUND_TRUTH))
    failure_modes = []
    for j in range(num_agents):
        failing = upfront[1 + j] if upfront else problem.evaluate(*drops[j])
        if not failing.adversarial:
            continue
        # latest start: dropping [start, end] fails, dropping nothing (start = T) passes
        start, failing = bisect(
            problem, 0, num_frames, lambda mid: none.with_drop(j, mid, num_frames - 1), Phase.HEURISTIC_START,
            agents[j], iterations, failing,
        )
        # earliest end: frames past the collision cannot matter, so the failing end starts there
        _, failing = bisect(
            problem, min(num_frames, failing.rollout.num_frames) - 1, start - 1,
            lambda mid: none.with_drop(j, start, mid), Phase.HEURISTIC_END, agents[j], iterations, failing,
        )
        failure_modes.append(failing)
    return failure_modes
