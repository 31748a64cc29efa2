"""Beyond the paper: when no drop collides, show nearby cars displaced until the ego collides.

Hiding a car only removes a reason for the ego to slow down or steer. When no drop makes it collide,
not even every car's at once (the blind rollout), an error that brings the ego into traffic may: a
car shown a few metres off its true place, so that the planner brakes or swerves into a real one.
This phase is a falsification search on the rollout's margin (`RolloutResult.margin`: its smallest
signed distance to a car at the ego's fault, so being rear-ended is no progress). It starts from
the conclusive rollout of lowest margin seen so far (ground truth, a single drop or the blind one),
and each step rolls out one candidate: the paper's proposal (a segment shown with one offset of up
to `max_offset` in a uniform direction, and yaw noise) on one of the `NEAREST` cars closest to the
ego in the ground truth or the current rollout, whether that car is hidden or seen there. A
conclusive candidate of lower margin becomes the current rollout; an inconclusive one is never
kept. It ends at a collision or after `steps` rollouts. A collision usually still hides or
displaces cars that play no part, so the phase then tries once the same errors on the nearest cars
only, everything else perceived perfectly, and keeps that if it still collides: the random search
or guided search then trades the remaining wrongness back for metric, as after a drop.
"""

from dataclasses import dataclass

import numpy as np

from advperc_ros.core.errors import PerceptionErrors
from advperc_ros.core.search.joint import relevance
from advperc_ros.core.search.problem import AttackProblem, Evaluation, Phase
from advperc_ros.core.search.random_search import RandomSearchConfig, propose

NEAREST = 4  # cars a candidate may show displaced: the nearest to the ego, in the ground truth or current rollout


@dataclass(frozen=True)
class Approach:
    start: Evaluation  # the conclusive rollout of lowest margin before the phase
    closest: Evaluation  # the conclusive rollout of lowest margin it reached: the collision, when it found one
    rollouts: int  # rolled out by the phase

    @property
    def collision(self) -> Evaluation | None:
        return self.closest if self.closest.adversarial else None


def worst_case(steps: int) -> int:
    """Rollouts the phase runs at most: its steps and, after a collision, the rollout of the nearest cars'
    errors alone."""
    return steps + 1 if steps > 0 else 0


def nearest(truth: Evaluation, current: Evaluation) -> np.ndarray:
    """Slots of the `NEAREST` cars closest to the ego in either rollout."""
    return np.asarray(relevance(truth, current)[:NEAREST], dtype=int)


def only(errors: PerceptionErrors, slots: np.ndarray) -> PerceptionErrors:
    """`errors` on `slots`, every other car perceived perfectly."""
    out = PerceptionErrors.none(*errors.fn.shape)
    for name in ("fn", "dx", "dy", "dyaw"):
        getattr(out, name)[:, slots] = getattr(errors, name)[:, slots]
    return out


def approach(problem: AttackProblem, seen: list[Evaluation], rng: np.random.Generator, cfg: RandomSearchConfig,
             steps: int) -> Approach:
    """The phase from the rollouts `seen` (the ground truth first): it stops at a collision, after
    `steps` rollouts, or at the problem's budget."""
    truth = seen[0]
    start = current = min((e for e in seen if not e.rollout.inconclusive), key=lambda e: e.rollout.margin)
    valid = problem.scenario.agents.valid
    first = len(problem.log)

    def room() -> bool:
        return problem.budget is None or len(problem.log) < problem.budget

    while len(problem.log) - first < steps and not current.adversarial and room():
        frames = current.rollout.num_frames
        where = np.zeros((frames, valid.shape[1]), dtype=bool)
        slots = nearest(truth, current)
        where[:, slots] = valid[:frames, slots]
        candidate = propose(current.errors, frames, rng, cfg, where)
        if candidate is None:  # no car near the ego is present
            break
        trial = problem.evaluate(candidate, Phase.APPROACH)
        if not trial.rollout.inconclusive and trial.rollout.margin < current.rollout.margin:
            current = trial
    if current.adversarial and room():
        alone = only(current.errors, nearest(truth, current))
        if not alone.equals(current.errors):
            trial = problem.evaluate(alone, Phase.APPROACH)
            if trial.adversarial:
                current = trial
    return Approach(start, current, len(problem.log) - first)
