"""How isolated is an attack? The paper's figure 5: perturb it and see whether it still works.

A perturbation of strength s flips every present object-frame between detected and dropped with
probability s and adds N(0, s^2) position noise (metres) to every offset. The fraction of perturbed
rollouts that still collide falling faster than their perception metric is what makes adversarial
errors "isolated": nearby inputs of similar quality do not break the planner.
"""

from dataclasses import dataclass

import numpy as np

from advperc_ros.core.perception_errors import PerceptionErrors
from advperc_ros.core.search.problem import AttackProblem, Phase

DEFAULT_STRENGTHS = (0.0, 0.01, 0.02, 0.05, 0.1, 0.2, 0.3, 0.5)


@dataclass(frozen=True)
class RobustnessPoint:
    """The robustness curve at one perturbation strength (paper figure 5): how often the perturbed
    attack still collides, and what it scores."""

    strength: float
    samples: int
    adversarial_fraction: float  # over conclusive rollouts
    mean_metric: float
    mean_nds: float
    mean_nds_t: float
    inconclusive: int


def perturb(errors: PerceptionErrors, present: np.ndarray, strength: float, rng: np.random.Generator) -> PerceptionErrors:
    """The attack `errors` perturbed at `strength`: each present object-frame flipped between detected
    and dropped with probability `strength`, N(0, strength^2) metres added to every offset."""
    out = errors.copy()
    flip = present & (rng.random(present.shape) < strength)
    out.fn[flip] = ~out.fn[flip]
    out.dx[:] += rng.normal(0.0, strength, present.shape)
    out.dy[:] += rng.normal(0.0, strength, present.shape)
    return out


def robustness_curve(
    problem: AttackProblem, errors: PerceptionErrors, strengths: tuple[float, ...], samples: int, rng: np.random.Generator
) -> list[RobustnessPoint]:
    """`samples` perturbations of the attack at each strength, rolled out through `problem`: a curve
    that falls at small strengths shows the attack is isolated, as the paper's adversarial errors are."""
    present = problem.scenario.agents.valid
    points = []
    for strength in strengths:
        runs = [problem.evaluate(perturb(errors, present, strength, rng), Phase.ROBUSTNESS) for _ in range(samples)]
        conclusive = [r for r in runs if r.rollout.inconclusive is None]
        points.append(
            RobustnessPoint(
                strength=float(strength),
                samples=samples,
                adversarial_fraction=float(np.mean([r.adversarial for r in conclusive])) if conclusive else float("nan"),
                mean_metric=float(np.mean([r.metric for r in runs])),
                mean_nds=float(np.mean([r.scores.nds for r in runs])),
                mean_nds_t=float(np.mean([r.scores.nds_t for r in runs])),
                inconclusive=len(runs) - len(conclusive),
            )
        )
    return points
