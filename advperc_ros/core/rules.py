"""Driving rules as real-valued functions: r < 0 is a violation.

The collision rule is the signed distance between the ego's box and each agent's box: the gap
when apart, minus the penetration depth when they overlap. r(tau) is its minimum over the rollout.
"""

import numpy as np

from advperc_ros.core.boxes import BoxSequence
from advperc_ros.core.geometry import signed_box_distance_pairs
from advperc_ros.core.scenario import EgoState


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
