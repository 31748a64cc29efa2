"""Scenes and a model with every perception-error-model term, shared by the PEM tests.

A scene: the ego driving along x at 8 m/s, cars in lanes 5 m apart driving along x at their own
speeds, so that their own motion over a latency is well above the position errors and a detection
is nearest its own car (the matching reads back what was injected).
"""

from dataclasses import replace

import numpy as np
from test_pem import TRUE

from advperc_ros.core.boxes import BoxSequence

LANES = (-10.0, -5.0, 5.0, 10.0, 0.0)  # the last car shares the ego's lane, ahead of it

EXTENDED = replace(
    TRUE, false_positive_rate=0.05, flip_near=0.02, flip_far=0.1, velocity_radial_scale=0.3,
    velocity_tangential_scale=0.2, velocity_nu=5.0, length_log_loc=0.02, length_log_std=0.08,
    width_log_loc=-0.01, width_log_std=0.05, latency=2.0, position_ar=0.6,
)


def moving_scene(rng: np.random.Generator, frames: int = 100) -> tuple[BoxSequence, np.ndarray]:
    """(truth, ego_xy) of one scene: 0.1 s frames, every car present throughout."""
    t = 0.1 * np.arange(frames)[:, None]
    agents = len(LANES)
    truth = BoxSequence.empty(frames, agents)
    truth.ids[:] = np.arange(1, agents + 1)
    truth.valid[:] = True
    speed = rng.uniform(5.0, 11.0, agents)
    start = rng.uniform(-25.0, 25.0, agents)
    start[-1] = rng.uniform(10.0, 25.0)
    truth.x[:] = start + speed * t
    truth.y[:] = np.array(LANES)
    truth.vx[:] = speed
    truth.length[:] = rng.uniform(4.0, 5.0, agents)
    truth.width[:], truth.height[:] = 1.9, 1.6
    return truth, np.stack([8.0 * t[:, 0], np.zeros(frames)], axis=1)
