"""Low-fidelity pseudo-occlusion (the paper's appendix), vectorised over frames and agents.

Each agent becomes an arc in ego-centred polar coordinates: the angular span of its box as seen
from the ego, at the distance of its nearest point. Its occlusion is the largest fraction of that
span covered by the span of any single closer agent. Not what a sensor would see (no height, no
union of occluders), hence "pseudo": an input feature for the perception error model.
"""

import numpy as np

from advperc_ros.core.boxes import BoxSequence
from advperc_ros.core.geometry import box_corners, wrap_angle


def _nearest_distance(rel_corners: np.ndarray) -> np.ndarray:
    """Distance from the origin to each box (..., 4, 2); 0 when the origin is inside."""
    a = rel_corners
    b = np.roll(rel_corners, -1, axis=-2)
    edge = b - a
    squared = np.maximum(np.einsum("...k,...k->...", edge, edge), 1e-12)  # empty slots have no extent
    t = np.clip(-np.einsum("...k,...k->...", a, edge) / squared, 0.0, 1.0)
    foot = a + t[..., None] * edge
    dist = np.linalg.norm(foot, axis=-1).min(axis=-1)
    cross = a[..., 0] * edge[..., 1] - a[..., 1] * edge[..., 0]  # origin left of every CCW edge: inside
    return np.where(np.all(cross >= 0.0, axis=-1), 0.0, dist)


def arcs(boxes: BoxSequence, ego_xy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(centre bearing, half-open span [lo, hi] relative to it, nearest distance), each (F, M)."""
    corners = box_corners(boxes.x, boxes.y, boxes.yaw, boxes.length, boxes.width)  # (F, M, 4, 2)
    rel = corners - ego_xy[:, None, None, :]
    bearing = np.arctan2(boxes.y - ego_xy[:, 1:2], boxes.x - ego_xy[:, 0:1])
    corner_angles = wrap_angle(np.arctan2(rel[..., 1], rel[..., 0]) - bearing[..., None])
    distance = _nearest_distance(rel)
    inside = distance == 0.0
    lo = np.where(inside, -np.pi, corner_angles.min(axis=-1))
    hi = np.where(inside, np.pi, corner_angles.max(axis=-1))
    return bearing, np.stack([lo, hi], axis=-1), distance


def occlusion(boxes: BoxSequence, ego_xy: np.ndarray) -> np.ndarray:
    """Occluded fraction in [0, 1] of every valid box, (F, M); nan where a slot is empty."""
    bearing, span, distance = arcs(boxes, ego_xy)
    lo_i, hi_i = span[..., 0][:, :, None], span[..., 1][:, :, None]
    # occluder j's span expressed around i's bearing
    shift = wrap_angle(bearing[:, None, :] - bearing[:, :, None])
    lo_j, hi_j = shift + span[..., 0][:, None, :], shift + span[..., 1][:, None, :]
    overlap = np.clip(np.minimum(hi_i, hi_j) - np.maximum(lo_i, lo_j), 0.0, None)
    closer = (distance[:, None, :] < distance[:, :, None]) & boxes.valid[:, None, :]
    fraction = np.where(closer, overlap / np.maximum(hi_i - lo_i, 1e-12), 0.0)
    out = np.clip(fraction.max(axis=2, initial=0.0), 0.0, 1.0)
    return np.where(boxes.valid, out, np.nan)
