"""Algorithm 1 of the paper: find influential agents, then bisect their dropped segment.

For each agent, drop its whole track; if that breaks the rule, bisect the latest start of a drop
that runs to the end, then the earliest end of a drop from that start. Bisection moves a bound
only on a definite verdict: an inconclusive rollout ends that bisection where it stands.
"""

from advperc_ros.core.errors import PerceptionErrors
from advperc_ros.core.search.problem import AttackProblem, Evaluation, GroundTruthFails


def heuristic_search(problem: AttackProblem, iterations: int = 3) -> list[Evaluation]:
    """Failure modes, one per influential agent, each the narrowest failing drop found."""
    scenario = problem.scenario
    num_frames, num_agents = scenario.agents.shape
    none = PerceptionErrors.none(num_frames, num_agents)
    truth = problem.evaluate(none, "ground_truth")
    if truth.rollout.inconclusive:
        raise GroundTruthFails(f"the ground-truth rollout is inconclusive: {truth.rollout.inconclusive}")
    if truth.adversarial:
        raise GroundTruthFails(
            f"the planner already collides with perfect perception "
            f"(min signed distance {truth.rollout.min_signed_distance:.3f} m); nothing to attack"
        )
    failure_modes = []
    for j in range(num_agents):
        agent = int(scenario.agents.ids[scenario.agents.valid[:, j].argmax(), j])
        failing = problem.evaluate(none.with_drop(j, 0, num_frames - 1), "heuristic_drop", agent)
        if not failing.adversarial:
            continue
        # latest start: dropping [lo, end] fails, dropping from hi on (hi = T: nothing) passes
        lo, hi = 0, num_frames
        for _ in range(iterations):
            mid = (lo + hi) // 2
            if mid in (lo, hi):
                break
            trial = problem.evaluate(none.with_drop(j, mid, num_frames - 1), "heuristic_start", agent)
            if trial.rollout.inconclusive:
                break
            if trial.adversarial:
                lo, failing = mid, trial
            else:
                hi = mid
        start = lo
        # earliest end: [start, hi] fails; frames past the collision cannot matter, so hi starts there
        lo, hi = start - 1, min(num_frames, failing.rollout.num_frames) - 1
        for _ in range(iterations):
            mid = (lo + hi) // 2
            if mid in (lo, hi):
                break
            trial = problem.evaluate(none.with_drop(j, start, mid), "heuristic_end", agent)
            if trial.rollout.inconclusive:
                break
            if trial.adversarial:
                hi, failing = mid, trial
            else:
                lo = mid
        failure_modes.append(failing)
    return failure_modes
