"""Beyond the paper, when ghosts are on: phantom obstacles, the ghost kind's counterpart of Algorithm 1.

Algorithm 1 finds failure modes by taking away what the planner sees, one agent at a time. A ghost
does the opposite, and its best-known failure is phantom braking: a car that is not there, standing
in the ego's lane just ahead of it, makes the planner brake or swerve, and the ego meets the traffic
it did not plan for (a follower that cannot stop in time, a neighbour it swerves into). Whether that
is a collision the verdict counts is the rule's call (`rule.at_fault_only` excuses being run into
from behind). One ghost for a couple of seconds costs a few false positives of precision, far less
than a dropped car's recall, so where such a failure exists it is the cheapest attack there is, and a
search that only narrows drops never starts from it: the guided rounds move from the best attack
so far, and every attack they hold then contains the drop.

So when the ghost kind is on, `PROBES` rollouts after the drops each show one standing ghost
`PROBE_LEAD` ahead of the ego on its ground-truth path for `PROBE_SPAN`, at starts spread evenly
over the ground-truth rollout. Each probe that collides is a failure mode beside the drops', and the
search method moves from the best of them all. With the paper's kinds nothing runs, so its results
stay the paper's to the bit.
"""

from collections.abc import Sequence

import numpy as np

from advperc_ros.core.perception_errors import ErrorSpace, PerceptionErrors
from advperc_ros.core.search import heuristic
from advperc_ros.core.search.problem import AttackProblem, Evaluation, LogRow, Phase

PROBES = 8  # phantom obstacles tried, at starts spread evenly over the ground-truth rollout
PROBE_LEAD = 0.8  # s ahead of the ego on its ground-truth path: nearer than its planner's comfortable stop
PROBE_SPAN = 2.5  # s the ghost stands there: longer than the tracker's coasting, so the planner acts on it
PHASES = {Phase.PHANTOM: heuristic.LABEL}  # failure modes beside Algorithm 1's, shown as its


def worst_case(space: ErrorSpace) -> int:
    """Rollouts the probes run: `PROBES` when the ghost kind is on, else none."""
    return PROBES if "ghost" in space.kinds else 0


def still_owed(logged: Sequence[LogRow], space: ErrorSpace) -> int:
    """Probes still to roll out, at most, having logged `logged` (fewer run on a short rollout)."""
    return worst_case(space) - len(logged)


def probes(truth: Evaluation, shape: tuple[int, int], dt: float, space: ErrorSpace) -> list[PerceptionErrors]:
    """The phantom obstacles for a scenario of `shape` (frames, agents) whose ground-truth rollout is
    `truth`: one ghost each, standing `PROBE_LEAD` ahead of where the ego then is, with its heading,
    from frames spread evenly over that rollout (fewer when it is too short for `PROBES` distinct ones)."""
    if worst_case(space) == 0:
        return []
    ego = truth.rollout.ego  # (K, 4): x, y, yaw, v
    lead = max(1, round(PROBE_LEAD / dt))
    span = max(1, round(PROBE_SPAN / dt))
    last = len(ego) - 1 - lead
    if last < 0:
        return []
    out = []
    for start in np.unique(np.linspace(0, last, PROBES).round().astype(int)):
        errors = space.blank(*shape)
        assert errors.ghost_on is not None and errors.ghost_x is not None and errors.ghost_y is not None
        assert errors.ghost_yaw is not None
        rows = slice(start, min(start + span, shape[0]))
        x, y, yaw, _ = ego[start + lead]
        errors.ghost_on[rows, 0] = True
        errors.ghost_x[rows, 0], errors.ghost_y[rows, 0], errors.ghost_yaw[rows, 0] = x, y, yaw
        out.append(errors)
    return out


def phantom_modes(problem: AttackProblem, truth: Evaluation, space: ErrorSpace) -> tuple[list[Evaluation], list[Evaluation]]:
    """(every probe's evaluation, the colliding ones: failure modes) of the phantom obstacles, rolled
    out as one batch (a backend may run them at once)."""
    scenario = problem.scenario
    tried = probes(truth, scenario.agents.shape, scenario.dt, space)
    if not tried:
        return [], []
    done = problem.evaluate_many([(errors, Phase.PHANTOM, -1) for errors in tried])
    return done, [evaluation for evaluation in done if evaluation.adversarial]
