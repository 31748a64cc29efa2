"""Planar geometry shared by scenarios, planners and rules: polylines and oriented boxes."""

import math
from dataclasses import dataclass, field
from typing import overload

import numpy as np

FloatArray = np.ndarray


@overload
def wrap_angle(angle: float) -> float: ...
@overload
def wrap_angle(angle: FloatArray) -> FloatArray: ...
def wrap_angle(angle: FloatArray | float) -> FloatArray | float:
    """Map angles to [-pi, pi). A Python float stays one: numpy's % on one number costs 40 times
    Python's, which computes it alike (fmod, then the divisor's sign), to the bit."""
    if type(angle) is float:
        return (angle + math.pi) % math.tau - math.pi
    return (np.asarray(angle) + np.pi) % (2.0 * np.pi) - np.pi


@dataclass(frozen=True)
class Polyline:
    """A 2D path parameterised by arc length; the route and lane centrelines use it."""

    points: FloatArray  # (M, 2)
    # derived in __post_init__: unit direction of each segment (M-1, 2) and arc length of each vertex (M,)
    _seg_dir: FloatArray = field(init=False, repr=False, compare=False)
    _s: FloatArray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        pts = np.asarray(self.points, dtype=float)
        keep = np.concatenate([[True], np.linalg.norm(np.diff(pts, axis=0), axis=1) > 1e-9])
        pts = pts[keep]
        if pts.shape[0] < 2:
            raise ValueError("a polyline needs at least two distinct points")
        object.__setattr__(self, "points", pts)
        seg = np.diff(pts, axis=0)
        seg_len = np.linalg.norm(seg, axis=1)
        object.__setattr__(self, "_seg_dir", seg / seg_len[:, None])
        object.__setattr__(self, "_s", np.concatenate([[0.0], np.cumsum(seg_len)]))

    @property
    def length(self) -> float:
        return float(self._s[-1])

    @property
    def stations(self) -> FloatArray:
        """Arc length of every vertex."""
        return self._s

    def _segment(self, s: FloatArray) -> np.ndarray:
        return np.clip(np.searchsorted(self._s, s, side="right") - 1, 0, len(self._s) - 2)

    def position(self, s: FloatArray | float) -> FloatArray:
        """Point at arc length s; beyond either end the end segment is extended straight."""
        s = np.asarray(s, dtype=float)
        i = self._segment(s)
        return self.points[i] + (s - self._s[i])[..., None] * self._seg_dir[i]

    def heading(self, s: FloatArray | float) -> FloatArray:
        d = self._seg_dir[self._segment(np.asarray(s, dtype=float))]
        return np.arctan2(d[..., 1], d[..., 0])

    def project(self, xy: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Arc length and signed lateral offset (left positive) of points, shape (..., 2)."""
        xy = np.asarray(xy, dtype=float)
        rel = xy[..., None, :] - self.points[:-1]  # (..., S, 2)
        seg_len = np.diff(self._s)
        along = np.einsum("...sk,sk->...s", rel, self._seg_dir)
        # the end segments extend to infinity so that points past the ends project onto them
        lo, hi = np.zeros_like(seg_len), seg_len.copy()
        lo[0], hi[-1] = -np.inf, np.inf
        t = np.clip(along, lo, hi)
        foot = self.points[:-1] + t[..., None] * self._seg_dir
        dist = np.linalg.norm(xy[..., None, :] - foot, axis=-1)
        best = np.argmin(dist, axis=-1)
        t_best = np.take_along_axis(t, best[..., None], axis=-1)[..., 0]
        s = self._s[best] + t_best
        d = self._seg_dir[best]
        rel_best = np.take_along_axis(rel, best[..., None, None], axis=-2)[..., 0, :]
        lateral = d[..., 0] * rel_best[..., 1] - d[..., 1] * rel_best[..., 0]
        return s, lateral


def box_corners(x: FloatArray | float, y: FloatArray | float, yaw: FloatArray, length: FloatArray | float,
                width: FloatArray | float) -> FloatArray:
    """Corners (..., 4, 2) of oriented boxes, counter-clockwise."""
    c, s = np.cos(yaw), np.sin(yaw)
    hl, hw = np.asarray(length) / 2.0, np.asarray(width) / 2.0
    local = np.array([[1.0, 1.0], [-1.0, 1.0], [-1.0, -1.0], [1.0, -1.0]])  # CCW
    lx = local[:, 0] * np.asarray(hl)[..., None]
    ly = local[:, 1] * np.asarray(hw)[..., None]
    cx = np.asarray(x)[..., None] + c[..., None] * lx - s[..., None] * ly
    cy = np.asarray(y)[..., None] + s[..., None] * lx + c[..., None] * ly
    return np.stack([cx, cy], axis=-1)


# box_corners' order: signs of (half length, half width) of each corner
_CORNER_SIGNS = np.array([[1.0, 1.0], [-1.0, 1.0], [-1.0, -1.0], [1.0, -1.0]])[:, None, None, :]


def signed_box_distance_pairs(boxes: FloatArray) -> FloatArray:
    """Gap between the two boxes of each pair when apart, minus the penetration depth when they overlap.

    boxes: (2, n, 5) C-contiguous; row 0 holds the pairs' first boxes, row 1 their second, each
    as (x, y, yaw, length, width). Pure numpy, equal to shapely's distance when apart (tested);
    a rollout calls this every frame, so it is written in few numpy calls: points are complex
    numbers (x + iy), headings unit complex numbers, and each box is looked at from the other's
    frame, both ways round at once. Overlap: separating axis theorem on the four box axes; the
    smallest projected overlap is the penetration depth (the minimum translation that separates
    them). Apart: the nearest points of two disjoint convex polygons include a vertex, so the
    gap is the smallest distance of a corner to the other box.
    """
    num = boxes.shape[1]
    centre = boxes[..., :2].view(complex)[..., 0]
    heading = np.exp(1j * boxes[..., 2])
    half = 0.5 * boxes[..., 3:]  # (2, n, 2): half length, half width
    other_half = half[::-1]
    back = np.conj(heading[::-1])
    rel = (centre - centre[::-1]) * back  # the centre in the other's frame
    rot = heading * back  # the heading in the other's frame
    cos_sin = np.abs(rot.view(float)).reshape(2, num, 2)
    reach = half[..., :1] * cos_sin + half[..., 1:] * cos_sin[..., ::-1]  # along the other's axes
    depth = (other_half + reach - np.abs(rel.view(float)).reshape(2, num, 2)).min(axis=(0, 2))
    corners = rel + rot * (half * _CORNER_SIGNS).view(complex)[..., 0]  # (4, 2, n) in the other's frame
    outside = np.maximum(np.abs(corners.view(float)).reshape(4, 2, num, 2) - other_half, 0.0)
    gap = np.hypot(outside[..., 0], outside[..., 1]).min(axis=(0, 1))
    return np.where(depth >= 0.0, -depth, gap)


def signed_box_distance(corners_a: FloatArray, corners_b: FloatArray) -> FloatArray:
    """signed_box_distance_pairs for boxes given by their corners (..., 4, 2), as box_corners
    makes them (rectangles), broadcasting."""
    a, b = np.broadcast_arrays(np.asarray(corners_a, float), np.asarray(corners_b, float))
    pairs = np.stack([_box_of_corners(a), _box_of_corners(b)]).reshape(2, -1, 5)
    return signed_box_distance_pairs(pairs).reshape(a.shape[:-2])


def _box_of_corners(corners: FloatArray) -> FloatArray:
    """(x, y, yaw, length, width) (..., 5) of rectangles from their corners in box_corners' order."""
    centre = 0.5 * (corners[..., 0, :] + corners[..., 2, :])
    along, across = corners[..., 0, :] - corners[..., 1, :], corners[..., 1, :] - corners[..., 2, :]
    return np.stack([
        centre[..., 0], centre[..., 1], np.arctan2(along[..., 1], along[..., 0]),
        np.hypot(along[..., 0], along[..., 1]), np.hypot(across[..., 0], across[..., 1]),
    ], axis=-1)
