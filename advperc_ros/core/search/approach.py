"""Beyond the paper: when no drop collides, show nearby cars wrongly until the ego collides.

Hiding a whole car only removes a reason for the ego to slow down or steer. When no such drop makes
it collide, not even every car's at once (the blind rollout), other errors may: a car shown a few
metres off its true place, so that the planner brakes or swerves into a real one, or a car hidden
for a while only, so that a planner that waited for it sets off and meets it. This phase is a
falsification search on the rollout's margins (`RolloutResult.counted`: its signed distances to the
cars where a contact would be the ego's fault, so a car closing in from behind is no progress). It
starts from the nearest of the conclusive rollouts so far (ground truth, single drops, the blind
one, the phantom obstacles when ghosts are on), and each step rolls out one candidate that shows one
of the `NEAREST` cars the ego comes closest to at its fault (in the ground truth or the current
rollout) wrongly over a segment of its frames, by a move drawn at even odds: the paper's proposal
(one offset of up to `max_offset` in a uniform direction, yaw noise), the car moved a uniform share
of the way towards the ego's path (traffic shown in its way, which a planner brakes or swerves for),
or the car hidden. A conclusive candidate that is `nearer` (each car's margin compared, nearest
first, to `MIN_GAIN`: progress behind a car the errors cannot move still counts) becomes the current
rollout; an inconclusive one is never kept. A walk ends at a collision, after `patience` rollouts in
a row that are not nearer, or after `steps` rollouts in all. A phantom obstacle's near miss (the ego
braking hard for a ghost) can be a dead end where the paper's kinds' start is not: when the walk
from one stalls, the phase walks again, with the steps left, from the nearest rollout that shows no
ghost, as the paper's kinds' search would have (one walk, the same to the bit, when the nearest
start shows none). A collision usually still hides or displaces cars that play no part, so the phase
then bisects for the fewest cars nearest the ego whose errors alone (everything else perceived
perfectly) still collide: the random search or guided search then trades the remaining wrongness
back for metric, as after a drop.
"""

import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cmp_to_key

import numpy as np

from advperc_ros.core.perception_errors import ErrorSpace, MoveContext, PerceptionErrors, kind_named
from advperc_ros.core.rollout import true_agents
from advperc_ros.core.search.heuristic import bisect
from advperc_ros.core.search.joint import relevance
from advperc_ros.core.search.problem import AttackProblem, Evaluation, LogRow, Phase, PhaseLabel
from advperc_ros.core.search.random_search import RandomSearchConfig, pick_segment, propose

PHASES = {Phase.APPROACH: PhaseLabel("approach", "tab:brown", "-")}
MIN_GAIN = 0.01  # m a candidate must bring the ego nearer to be kept: a planner's numerical noise is no progress
NEAREST = 4  # cars a candidate may show displaced: the nearest to the ego, in the ground truth or current rollout


@dataclass(frozen=True)
class Approach:
    """What the approach phase did, when no drop collided: where it started and how near a collision
    at the ego's fault it came, which the no-collision report gives as the search's best effort."""

    start: Evaluation  # the conclusive rollout of lowest margin before the phase
    closest: Evaluation  # the conclusive rollout of lowest margin it reached: the collision, when it found one
    rollouts: int  # rolled out by the phase

    @property
    def collision(self) -> Evaluation | None:
        return self.closest if self.closest.adversarial else None


def worst_case(steps: int, num_agents: int) -> int:
    """Rollouts the phase runs at most: its steps and, after a collision, the bisection for the fewest
    nearest cars whose errors alone still collide."""
    return steps + math.ceil(math.log2(max(num_agents, 1))) if steps > 0 else 0


def still_owed(logged: Sequence[LogRow], steps: int, num_agents: int) -> int:
    """Rollouts `approach` may still run, at most, having logged `logged`."""
    return worst_case(steps, num_agents) - len(logged)


def nearest(truth: Evaluation, current: Evaluation) -> np.ndarray:
    """Slots of the `NEAREST` cars the ego comes closest to at its fault in either rollout (a car only
    ever behind it cannot be hit at its fault)."""
    closest = np.minimum(truth.rollout.counted.min(axis=0, initial=np.inf),
                         current.rollout.counted.min(axis=0, initial=np.inf))
    order = np.argsort(closest, kind="stable")[:NEAREST]
    return order[np.isfinite(closest[order])]


def nearer(trial: Evaluation, current: Evaluation) -> bool:
    """Whether `trial` brings the ego nearer a collision at its fault than `current`: its cars' margins
    (each car's smallest counted distance), nearest first, compared in order, a difference under
    `MIN_GAIN` counting as a tie. The nearest car alone would be blind to progress behind a car the
    errors cannot move (a car beside a lane-keeping ego stays as near however it brakes)."""
    ours, theirs = (np.sort(e.rollout.counted.min(axis=0, initial=np.inf)) for e in (trial, current))
    for a, b in zip(ours, theirs):
        if not (np.isfinite(a) or np.isfinite(b)) or abs(a - b) >= MIN_GAIN:
            return bool(a < b)
    return False


def only(errors: PerceptionErrors, slots: np.ndarray) -> PerceptionErrors:
    """`errors` on `slots`, every other car perceived perfectly (ghosts are no car: they all stay)."""
    out = PerceptionErrors.none(*errors.shape, errors.kinds, errors.ghost_slots)
    kept = out.arrays()
    for name, array in errors.arrays().items():
        if name.startswith("ghost_"):
            kept[name][:] = array
        else:
            kept[name][:, slots] = array[:, slots]
    return out


def into_path(errors: PerceptionErrors, frames: int, rng: np.random.Generator, cfg: RandomSearchConfig,
              where: np.ndarray, agents_xy: np.ndarray, path: np.ndarray) -> PerceptionErrors | None:
    """A segment of a car (uniform over its frames in `where`) shown moved towards the nearest point of
    the ego's path `path` ((K, 2)) by a U(0, 1) share of the way, at most `max_offset`: traffic shown
    in the ego's way."""
    picked = pick_segment(where[:frames], rng)
    if picked is None:
        return None
    j, span = picked
    share = rng.uniform(0.0, 1.0)
    xy = agents_xy[span, j]  # (n, 2)
    nearest_point = path[np.argmin(((xy[:, None, :] - path[None, :, :]) ** 2).sum(axis=2), axis=1)]
    offset = share * (nearest_point - xy)
    length = np.hypot(offset[:, 0], offset[:, 1])
    offset *= np.minimum(1.0, cfg.max_offset / np.maximum(length, 1e-12))[:, None]
    out = errors.copy()
    out.fn[span, j] = False
    out.dx[span, j], out.dy[span, j] = offset[:, 0], offset[:, 1]
    out.dyaw[span, j] = 0.0
    return out


def hide(errors: PerceptionErrors, rng: np.random.Generator, where: np.ndarray) -> PerceptionErrors | None:
    """A segment of a car (uniform over its frames in `where`) hidden: unlike a whole-track drop, the
    car is seen before and after, so a planner that waited for it may set off and meet it."""
    picked = pick_segment(where, rng)
    if picked is None:
        return None
    j, span = picked
    out = errors.copy()
    out.fn[span, j] = True
    out.dx[span, j] = out.dy[span, j] = out.dyaw[span, j] = 0.0
    return out


def approach(problem: AttackProblem, seen: list[Evaluation], rng: np.random.Generator, cfg: RandomSearchConfig,
             steps: int, patience: int, space: ErrorSpace = ErrorSpace()) -> Approach:
    """The phase from the rollouts `seen` (the ground truth first): a walk stops at a collision, after
    `patience` rollouts in a row that bring the ego no nearer, after `steps` rollouts in all, or at the
    problem's budget; a walk from a phantom obstacle that stalls is followed by one from the nearest
    rollout without ghosts. With extended kinds on (`space`), each kind's moves join the paper's three at
    even odds, acting on the same nearest cars (ghosts: on the ego's path ahead)."""
    extended = [move for kind in space.kinds for _, move in kind_named(kind).moves]
    truth = seen[0]
    def order(a: Evaluation, b: Evaluation) -> int:
        return -1 if nearer(a, b) else int(nearer(b, a))

    conclusive = [e for e in seen if not e.rollout.inconclusive]
    start = min(conclusive, key=cmp_to_key(order))
    # a phantom obstacle's near miss may lead nowhere: the paper's kinds' start is walked from next
    without_ghosts = [e for e in conclusive if "ghost" not in e.errors.used_kinds(e.rollout.num_frames)]
    fallback = min(without_ghosts, key=cmp_to_key(order)) if without_ghosts else None
    valid = problem.scenario.agents.valid
    agents_xy = np.stack([problem.scenario.agents.x, problem.scenario.agents.y], axis=2)
    first = len(problem.log)

    def room() -> bool:
        return len(problem.log) - first < steps and (problem.budget is None or len(problem.log) < problem.budget)

    def walk(current: Evaluation) -> Evaluation:
        """From `current`, one candidate a rollout, until a collision, `patience` rollouts in a row not
        nearer, or no room: the nearest rollout reached."""
        stalled = 0
        while stalled < patience and not current.adversarial and room():
            frames = current.rollout.num_frames
            where = np.zeros((frames, valid.shape[1]), dtype=bool)
            slots = nearest(truth, current)
            where[:, slots] = valid[:frames, slots]
            move = rng.integers(3 + len(extended))
            if move == 0:
                candidate = propose(current.errors, frames, rng, cfg, where)
            elif move == 1:
                candidate = into_path(current.errors, frames, rng, cfg, where, agents_xy, current.rollout.ego_xy)
            elif move == 2:
                candidate = hide(current.errors, rng, where)
            else:
                context = MoveContext(true_agents(current.rollout, problem.scenario), current.rollout.ego, space,
                                      problem.scenario.dt, where)
                candidate = extended[move - 3](current.errors, frames, rng, context)
                if candidate is None:  # that move had nothing to act on (a ghost to take away): another draw
                    continue
            if candidate is None:  # no car near the ego is present
                break
            trial = problem.evaluate(candidate, Phase.APPROACH)
            stalled += 1
            if not trial.rollout.inconclusive and nearer(trial, current):
                current, stalled = trial, 0
        return current

    current = walk(start)
    if not current.adversarial and fallback is not None and fallback is not start and room():
        again = walk(fallback)
        current = again if again.adversarial or nearer(again, current) else current
    if current.adversarial:
        current = fewest(problem, truth, current)
    return Approach(start, current, len(problem.log) - first)


def fewest(problem: AttackProblem, truth: Evaluation, collision: Evaluation) -> Evaluation:
    """The collision with the errors of only the fewest cars nearest the ego that still collide, every
    other car perceived perfectly: bisected over the cars by closest approach (as the joint drops'
    reduction), so a collision found from the blind rollout does not hide the whole scene (nuScenes'
    AP ignores recall below 10 %: with most cars hidden every score is 0, and no single flip back
    raises it)."""
    order = relevance(truth, collision)
    wrong = collision.errors.attacked() | (collision.errors.dyaw != 0)
    attacked = [i for i, j in enumerate(order) if wrong[:, j].any()]
    if not attacked:  # ghosts alone: no car's errors to do without
        return collision
    return bisect(problem, attacked[-1] + 1, 0, lambda n: only(collision.errors, np.asarray(order[:n], dtype=int)),
                  Phase.APPROACH, -1, math.ceil(math.log2(max(len(order), 1))), collision)[1]
