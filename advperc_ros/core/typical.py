"""Typical (non-adversarial) perception errors, and the paper's check that they cause no collision.

Two sources: the perception error model (the paper's criterion: 100 PEM samples per scenario, no
collision), whose samples hold every kind of error the model has terms for (the calibrated default's:
ghosts, flips, velocity and size errors, persistent position errors), and a model-free stand-in of
independent Gaussian position and yaw noise with isolated single-frame drops. A collision under
typical errors is a finding about the stack, reported as such, not a failure of the check.
"""

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from advperc_ros.core.pem import PEM
from advperc_ros.core.perception_errors import PerceptionErrors
from advperc_ros.core.rollout import RolloutResult
from advperc_ros.core.scenario import Scenario


@dataclass(frozen=True)
class TypicalErrorConfig:
    """The model-free stand-in for typical errors: Gaussian position and yaw noise, isolated drops."""

    position_std: float = 0.2  # m, per axis
    yaw_std: float = 0.05  # rad
    drop_probability: float = 0.05  # per object-frame, never two frames in a row


def sample_typical_errors(shape: tuple[int, int], rng: np.random.Generator, cfg: TypicalErrorConfig) -> PerceptionErrors:
    """Typical errors of a scenario's shape (frames x agents) under `cfg`: noise everywhere, single-frame
    drops only, so no car disappears for long."""
    fn = rng.random(shape) < cfg.drop_probability
    fn[1:] &= ~fn[:-1]  # single-frame drops only
    return PerceptionErrors(
        dx=rng.normal(0.0, cfg.position_std, shape),
        dy=rng.normal(0.0, cfg.position_std, shape),
        dyaw=rng.normal(0.0, cfg.yaw_std, shape),
        fn=fn,
    )


@dataclass(frozen=True)
class TypicalCheck:
    """The paper's check that typical errors cause no collision: an attack on a stack that fails under
    typical errors would say nothing about adversarial ones."""

    samples: int
    collisions: int
    inconclusive: int
    min_signed_distance: float  # closest approach over all conclusive rollouts
    kinds: tuple[str, ...]  # the error kinds the samples held: what the check exercised

    @property
    def passed(self) -> bool:
        return self.collisions == 0 and self.inconclusive == 0


def check_typical(
    scenario: Scenario,
    run_rollout: Callable[[PerceptionErrors], RolloutResult],
    pem: PEM,
    samples: int,
    rng: np.random.Generator,
) -> TypicalCheck:
    """Roll out PEM-sampled errors. The ego path the PEM conditions on (range, occlusion, where ghosts
    appear) is the ground-truth rollout's: errors are sampled before a rollout, as the attack's are."""
    ego_xy = run_rollout(PerceptionErrors.none(*scenario.agents.shape)).ego_xy
    ego_xy = np.concatenate([ego_xy, np.repeat(ego_xy[-1:], scenario.num_frames - len(ego_xy), axis=0)])
    tensors = [pem.sample(scenario.agents, ego_xy, rng) for _ in range(samples)]
    results = [run_rollout(errors) for errors in tensors]
    conclusive = [r for r in results if r.inconclusive is None]
    return TypicalCheck(
        samples=samples,
        collisions=sum(r.collided for r in conclusive),
        inconclusive=samples - len(conclusive),
        min_signed_distance=min((r.min_signed_distance for r in conclusive), default=float("nan")),
        kinds=tensors[0].kinds if tensors else (),
    )
