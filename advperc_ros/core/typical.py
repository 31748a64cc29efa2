"""Typical (non-adversarial) perception errors: the robustness stand-in until the PEM exists.

Independent Gaussian position and yaw noise on every detection and isolated single-frame drops:
a stack tuned as the paper's must not collide under these.
"""

from dataclasses import dataclass

import numpy as np

from advperc_ros.core.errors import PerceptionErrors


@dataclass(frozen=True)
class TypicalErrorConfig:
    position_std: float = 0.2  # m, per axis
    yaw_std: float = 0.05  # rad
    drop_probability: float = 0.05  # per object-frame, never two frames in a row


def sample_typical_errors(shape: tuple[int, int], rng: np.random.Generator, cfg: TypicalErrorConfig) -> PerceptionErrors:
    fn = rng.random(shape) < cfg.drop_probability
    fn[1:] &= ~fn[:-1]  # single-frame drops only
    return PerceptionErrors(
        dx=rng.normal(0.0, cfg.position_std, shape),
        dy=rng.normal(0.0, cfg.position_std, shape),
        dyaw=rng.normal(0.0, cfg.yaw_std, shape),
        fn=fn,
    )
