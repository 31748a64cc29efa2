"""Driving rules as real-valued functions: r < 0 is a violation.

The collision rule is the signed distance between the ego's box and each agent's box: the gap
when apart, minus the penetration depth when they overlap. r(tau) is its minimum over the rollout.

At-fault collisions (nuPlan's "no ego at-fault collisions"): a contact is not the ego's fault when
the ego is stopped, or when the agent hits it from behind (the agent's centre lies behind the ego's
rear bumper in the ego's frame). No closing-speed test is needed for the latter: agents replay
their recorded motion and the ego never reverses, so an agent behind the rear bumper that touches
the ego has come from behind.
"""

import numpy as np

from advperc_ros.core.boxes import BoxSequence
from advperc_ros.core.geometry import signed_box_distance_pairs
from advperc_ros.core.scenario import EgoState

STOPPED_SPEED = 0.05  # m/s: below it the ego is stopped (nuPlan's stopped-speed threshold)


def collision_distances(
    ego: EgoState, ego_length: float, ego_width: float, agents: BoxSequence, k: int
) -> np.ndarray:
    """Signed distance from the ego to every agent slot at frame k; +inf for absent agents."""
    pairs = np.empty((2, agents.shape[1], 5))
    pairs[0] = ego.x, ego.y, ego.yaw, ego_length, ego_width
    pairs[1] = np.array([agents.x[k], agents.y[k], agents.yaw[k], agents.length[k], agents.width[k]]).T
    distance = signed_box_distance_pairs(pairs)
    # absent slots hold padding (zeros, or nan): cheaper to measure along than to leave out
    return np.where(agents.valid[k], distance, np.inf)


def not_at_fault(ego: np.ndarray, ego_length: float, agents: BoxSequence, distances: np.ndarray) -> np.ndarray:
    """(K, N) contacts that are not the ego's fault, from the ego's states `ego` (K, 4: x, y, yaw,
    v) at frames 0..K-1 and their signed `distances` (K, N): the ego stopped, or hit from behind."""
    frames = ego.shape[0]
    x, y, yaw, v = (ego[:, i : i + 1] for i in range(4))
    along = (agents.x[:frames] - x) * np.cos(yaw) + (agents.y[:frames] - y) * np.sin(yaw)
    return (distances < 0.0) & ((v < STOPPED_SPEED) | (along < -ego_length / 2))
