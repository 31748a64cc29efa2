"""Driving rules as real-valued functions: r < 0 is a violation.

The collision rule is the signed distance between the ego's box and each agent's box: the gap
when apart, minus the penetration depth when they overlap. r(tau) is its minimum over the rollout.
"""

import numpy as np

from advperc_ros.core.boxes import BoxSequence
from advperc_ros.core.geometry import box_corners, signed_box_distance
from advperc_ros.core.scenario import EgoState


def collision_distances(
    ego: EgoState, ego_length: float, ego_width: float, agents: BoxSequence, k: int
) -> np.ndarray:
    """Signed distance from the ego to every agent slot at frame k; +inf for absent agents."""
    out = np.full(agents.shape[1], np.inf)
    mask = agents.valid[k]
    if mask.any():
        ego_box = box_corners(ego.x, ego.y, ego.yaw, ego_length, ego_width)
        boxes = box_corners(
            agents.x[k, mask], agents.y[k, mask], agents.yaw[k, mask], agents.length[k, mask], agents.width[k, mask]
        )
        out[mask] = signed_box_distance(ego_box[None], boxes)
    return out
