"""Algorithm 1 of the paper: find influential agents, then bisect their dropped segment.

For each agent, drop its whole track; if that breaks the rule, bisect the latest start of a drop
that runs to the end, then the earliest end of a drop from that start. Bisection moves a bound
only on a definite verdict: an inconclusive rollout ends that bisection where it stands.
"""

from collections import Counter
from collections.abc import Callable, Generator, Sequence
from dataclasses import dataclass
from typing import TypeVar

from advperc_ros.core.perception_errors import PerceptionErrors
from advperc_ros.core.scenario import Scenario
from advperc_ros.core.search.problem import AttackProblem, Evaluation, LogRow, Phase, PhaseLabel
from advperc_ros.exceptions import GroundTruthFails

Segments = dict[int, tuple[int, int]]  # slot -> (first, last) dropped frame, inclusive
T = TypeVar("T")
LABEL = PhaseLabel("heuristic", "tab:orange", "-")  # Algorithm 1, and the phantom obstacles and joint drops beside it
PHASES = dict.fromkeys((Phase.GROUND_TRUTH, Phase.HEURISTIC_DROP, Phase.HEURISTIC_START, Phase.HEURISTIC_END), LABEL)


@dataclass(frozen=True)
class Heuristic:
    """What Algorithm 1 rolled out: what the joint drops start from when no agent is influential."""

    truth: Evaluation  # perfect perception
    drops: list[Evaluation]  # each agent's whole-track drop, by slot
    modes: list[Evaluation]  # failure modes, one per influential agent, each the narrowest failing drop found


def dropping(shape: tuple[int, int], segments: Segments) -> PerceptionErrors:
    """Errors that drop each slot's segment and nothing else."""
    errors = PerceptionErrors.none(*shape)
    for j, (first, last) in segments.items():
        errors.fn[first : last + 1, j] = True
    return errors


Request = tuple[PerceptionErrors, Phase, int]  # what to roll out: errors, phase, agent id
Narrowing = Generator[Request, Evaluation, tuple[Segments, Evaluation]]


def bisecting(fails: int, passes: int, errors_at: Callable[[int], PerceptionErrors], phase: Phase, agent: int,
              iterations: int, failing: Evaluation) -> Generator[Request, Evaluation, tuple[int, Evaluation]]:
    """Move the failing bound towards the passing one: yields each rollout it needs, is sent its
    evaluation, and returns the failing bound with its evaluation."""
    for _ in range(iterations):
        mid = (fails + passes) // 2
        if mid in (fails, passes):
            break
        trial = yield errors_at(mid), phase, agent
        if trial.rollout.inconclusive:
            break
        if trial.adversarial:
            fails, failing = mid, trial
        else:
            passes = mid
    return fails, failing


def narrowing(scenario: Scenario, segments: Segments, j: int, iterations: int, failing: Evaluation,
              phases: tuple[Phase, Phase] = (Phase.HEURISTIC_START, Phase.HEURISTIC_END)) -> Narrowing:
    """Bisect slot j's whole-track drop, the other segments held: its latest start of a drop running to
    the end, then the earliest end; `failing` is the rollout of `segments`. Yields its rollouts (each
    depends on the last) and returns the narrowed segments with their evaluation."""
    num_frames = scenario.num_frames
    agent = scenario.agent_id(j)
    shape = scenario.agents.shape
    # latest start: dropping [start, end] fails, dropping nothing (start = T) passes
    start, failing = yield from bisecting(0, num_frames, lambda mid: dropping(shape, {**segments, j: (mid, num_frames - 1)}),
                                          phases[0], agent, iterations, failing)
    # earliest end: frames past the collision cannot matter, so the failing end starts there
    end, failing = yield from bisecting(min(num_frames, failing.rollout.num_frames) - 1, start - 1,
                                        lambda mid: dropping(shape, {**segments, j: (start, mid)}), phases[1], agent,
                                        iterations, failing)
    return {**segments, j: (start, end)}, failing


def run_one(problem: AttackProblem, steps: Generator[Request, Evaluation, T]) -> T:
    """Drive a generator of rollouts one at a time; its result."""
    try:
        request = next(steps)
        while True:
            request = steps.send(problem.evaluate(*request))
    except StopIteration as done:
        return done.value


def run_lockstep(problem: AttackProblem, steps: list[Generator[Request, Evaluation, T]]) -> list[T]:
    """Drive independent generators together: each wave rolls out the next request of every one that
    is not done as one batch, which a backend may run at once. Each generator sees exactly the
    rollouts it would see alone, so the results are those of `run_one` on each; only the log's order
    differs. A wave larger than the rollouts left is cut to them."""
    results: dict[int, T] = {}
    pending: dict[int, Request] = {}
    for i, gen in enumerate(steps):
        try:
            pending[i] = next(gen)
        except StopIteration as done:
            results[i] = done.value
    while pending:
        left = len(pending) if problem.budget is None else max(1, problem.budget - len(problem.log))
        wave = list(pending)[:left]
        for i, trial in zip(wave, problem.evaluate_many([pending[i] for i in wave])):
            try:
                pending[i] = steps[i].send(trial)
            except StopIteration as done:
                results[i] = done.value
                del pending[i]
    return [results[i] for i in range(len(steps))]


def narrow(problem: AttackProblem, segments: Segments, j: int, iterations: int, failing: Evaluation,
           phases: tuple[Phase, Phase] = (Phase.HEURISTIC_START, Phase.HEURISTIC_END)) -> tuple[Segments, Evaluation]:
    """`narrowing`, rolled out one rollout at a time."""
    return run_one(problem, narrowing(problem.scenario, segments, j, iterations, failing, phases))


def bisect(problem: AttackProblem, fails: int, passes: int, errors_at: Callable[[int], PerceptionErrors], phase: Phase,
           agent: int, iterations: int, failing: Evaluation) -> tuple[int, Evaluation]:
    """`bisecting`, rolled out one rollout at a time."""
    return run_one(problem, bisecting(fails, passes, errors_at, phase, agent, iterations, failing))


def check_ground_truth(truth: Evaluation, rule: str | None = None) -> None:
    """Refuse to attack a stack that breaks the rule with perfect perception (`rule`: the attacked rule,
    when it is not a contact rule)."""
    if truth.rollout.inconclusive:
        raise GroundTruthFails(f"the ground-truth rollout is inconclusive: {truth.rollout.inconclusive}")
    if truth.adversarial and rule is not None:
        raise GroundTruthFails(f"the stack already breaks rule {rule} with perfect perception "
                               f"(r = {truth.rollout.margin:.3f}); nothing to attack")
    if truth.adversarial:
        raise GroundTruthFails(
            f"the planner already collides with perfect perception "
            f"(min signed distance {truth.rollout.min_signed_distance:.3f} m); nothing to attack"
        )


def heuristic_search(problem: AttackProblem, iterations: int = 3, batched: bool = False) -> Heuristic:
    """Failure modes, one per influential agent. In the paper's order (each agent's drop, then its
    bisections), or `batched` (the guided method): the ground truth and every agent's drop roll out
    as one batch, then the influential agents' bisections in lockstep, a batch per step, which a
    backend may run at once; the same rollouts and failure modes either way, logged in another order."""
    scenario = problem.scenario
    num_frames, num_agents = scenario.agents.shape
    perfect = (PerceptionErrors.none(num_frames, num_agents), Phase.GROUND_TRUTH, -1)
    whole = [(dropping(scenario.agents.shape, {j: (0, num_frames - 1)}), Phase.HEURISTIC_DROP, scenario.agent_id(j))
             for j in range(num_agents)]
    upfront = problem.evaluate_many([perfect, *whole]) if batched else None
    truth = upfront[0] if upfront else problem.evaluate(*perfect)
    check_ground_truth(truth, None if problem.attacked_rule is None else problem.attacked_rule.name)
    if upfront:  # the influential agents' bisections are independent: in lockstep
        drops = upfront[1:]
        influential = [j for j in range(num_agents) if drops[j].adversarial]
        narrowed = run_lockstep(problem, [narrowing(scenario, {j: (0, num_frames - 1)}, j, iterations, drops[j])
                                          for j in influential])
        return Heuristic(truth, drops, [mode for _, mode in narrowed])
    drops, modes = [], []
    for j in range(num_agents):
        drops.append(problem.evaluate(*whole[j]))
        if drops[-1].adversarial:
            modes.append(narrow(problem, {j: (0, num_frames - 1)}, j, iterations, drops[-1])[1])
    return Heuristic(truth, drops, modes)


def still_owed(logged: Sequence[LogRow], num_agents: int, iterations: int, batched: bool) -> int:
    """Rollouts `heuristic_search` may still run, at most, having logged `logged`: the ground truth,
    each agent's drop not rolled out yet with the 2 x `iterations` bisections it runs should it
    collide, and what the bisections of the drops that collided may still run. `batched`: every drop
    rolls out before any bisection; else an agent's bisections are over once the next agent's drop is."""
    drops = [row for row in logged if row.phase == Phase.HEURISTIC_DROP]
    owed = (not any(row.phase == Phase.GROUND_TRUTH for row in logged)) + (num_agents - len(drops)) * (1 + 2 * iterations)
    bisected = {Phase.HEURISTIC_START: Counter[int](), Phase.HEURISTIC_END: Counter[int]()}  # rollouts per agent
    ended = set()  # (agent, phase) of the bisections an inconclusive rollout ended
    for row in logged:
        if row.phase in bisected:
            bisected[row.phase][row.agent] += 1
            if row.inconclusive:
                ended.add((row.agent, row.phase))
    starts, ends = bisected[Phase.HEURISTIC_START], bisected[Phase.HEURISTIC_END]
    for drop in drops if batched else drops[-1:]:
        if drop.collided:
            agent = drop.agent
            start_over = ends[agent] > 0 or (agent, Phase.HEURISTIC_START) in ended
            end_over = (agent, Phase.HEURISTIC_END) in ended
            owed += (0 if start_over else iterations - starts[agent]) + (0 if end_over else iterations - ends[agent])
    return owed
