"""Beyond the paper: when no drop collides, show nearby cars displaced until the ego collides.

Hiding a car only removes a reason for the ego to slow down or steer. When no drop makes it collide,
not even every car's at once (the blind rollout), an error that brings the ego into traffic may: a
car shown a few metres off its true place, so that the planner brakes or swerves into a real one.
This phase is a falsification search on the rollout's margin (`RolloutResult.margin`: its smallest
signed distance to a car at the ego's fault, so being rear-ended is no progress). It starts from
the conclusive rollout of lowest margin seen so far (ground truth, a single drop or the blind one),
and each step rolls out one candidate that shows one of the `NEAREST` cars closest to the ego (in
the ground truth or the current rollout, hidden or seen there) displaced over a segment of its
frames up to the current closest approach (later errors cannot bring the ego nearer at it), by a
move drawn at even odds: the paper's proposal (one offset of up to `max_offset` in a uniform
direction, yaw noise), or the car moved a uniform share of the way towards the ego's path (traffic
shown in its way, which a planner brakes or swerves for). A conclusive candidate that brings the ego
at least `MIN_GAIN` nearer becomes the current rollout; an inconclusive one is never kept. It ends
at a collision or after `steps` rollouts. A collision usually still hides or displaces cars that
play no part, so the phase then bisects for the fewest cars nearest the ego whose errors alone
(everything else perceived perfectly) still collide: the random search or guided search then
trades the remaining wrongness back for metric, as after a drop.
"""

import math
from dataclasses import dataclass

import numpy as np

from advperc_ros.core.errors import PerceptionErrors
from advperc_ros.core.search.heuristic import bisect
from advperc_ros.core.search.joint import relevance
from advperc_ros.core.search.problem import AttackProblem, Evaluation, Phase
from advperc_ros.core.search.random_search import RandomSearchConfig, pick_segment, propose

MIN_GAIN = 0.01  # m a candidate must bring the ego nearer to be kept: a planner's numerical noise is no progress
NEAREST = 4  # cars a candidate may show displaced: the nearest to the ego, in the ground truth or current rollout


@dataclass(frozen=True)
class Approach:
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


def nearest(truth: Evaluation, current: Evaluation) -> np.ndarray:
    """Slots of the `NEAREST` cars closest to the ego in either rollout."""
    return np.asarray(relevance(truth, current)[:NEAREST], dtype=int)


def only(errors: PerceptionErrors, slots: np.ndarray) -> PerceptionErrors:
    """`errors` on `slots`, every other car perceived perfectly."""
    out = PerceptionErrors.none(*errors.fn.shape)
    for name in ("fn", "dx", "dy", "dyaw"):
        getattr(out, name)[:, slots] = getattr(errors, name)[:, slots]
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


def approach(problem: AttackProblem, seen: list[Evaluation], rng: np.random.Generator, cfg: RandomSearchConfig,
             steps: int) -> Approach:
    """The phase from the rollouts `seen` (the ground truth first): it stops at a collision, after
    `steps` rollouts, or at the problem's budget."""
    truth = seen[0]
    start = current = min((e for e in seen if not e.rollout.inconclusive), key=lambda e: e.rollout.margin)
    valid = problem.scenario.agents.valid
    agents_xy = np.stack([problem.scenario.agents.x, problem.scenario.agents.y], axis=2)
    first = len(problem.log)

    def room() -> bool:
        return problem.budget is None or len(problem.log) < problem.budget

    while len(problem.log) - first < steps and not current.adversarial and room():
        # up to the frame of closest approach: later errors cannot bring the ego nearer at it
        frames = int(np.argmin(current.rollout.counted.min(axis=1, initial=np.inf))) + 1
        where = np.zeros((frames, valid.shape[1]), dtype=bool)
        slots = nearest(truth, current)
        where[:, slots] = valid[:frames, slots]
        if rng.integers(2):
            candidate = propose(current.errors, frames, rng, cfg, where)
        else:
            candidate = into_path(current.errors, frames, rng, cfg, where, agents_xy, current.rollout.ego_xy)
        if candidate is None:  # no car near the ego is present
            break
        trial = problem.evaluate(candidate, Phase.APPROACH)
        if not trial.rollout.inconclusive and trial.rollout.margin < current.rollout.margin - MIN_GAIN:
            current = trial
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
    attacked = [i for i, j in enumerate(order) if collision.errors.fn[:, j].any() or collision.errors.dx[:, j].any()
                or collision.errors.dy[:, j].any() or collision.errors.dyaw[:, j].any()]
    return bisect(problem, attacked[-1] + 1, 0, lambda n: only(collision.errors, np.asarray(order[:n], dtype=int)),
                  Phase.APPROACH, -1, math.ceil(math.log2(max(len(order), 1))), collision)[1]
