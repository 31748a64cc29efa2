"""Planar geometry shared by scenarios, planners and rules: polylines and oriented boxes."""

from dataclasses import dataclass

import numpy as np
import shapely

FloatArray = np.ndarray


def wrap_angle(angle: FloatArray | float) -> FloatArray:
    """Map angles to [-pi, pi)."""
    return (np.asarray(angle) + np.pi) % (2.0 * np.pi) - np.pi


@dataclass(frozen=True)
class Polyline:
    """A 2D path parameterised by arc length; the route and lane centrelines use it."""

    points: FloatArray  # (M, 2)

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


def box_corners(x: FloatArray, y: FloatArray, yaw: FloatArray, length: FloatArray, width: FloatArray) -> FloatArray:
    """Corners (..., 4, 2) of oriented boxes, counter-clockwise."""
    c, s = np.cos(yaw), np.sin(yaw)
    hl, hw = np.asarray(length) / 2.0, np.asarray(width) / 2.0
    local = np.array([[1.0, 1.0], [-1.0, 1.0], [-1.0, -1.0], [1.0, -1.0]])  # CCW
    lx = local[:, 0] * np.asarray(hl)[..., None]
    ly = local[:, 1] * np.asarray(hw)[..., None]
    cx = np.asarray(x)[..., None] + c[..., None] * lx - s[..., None] * ly
    cy = np.asarray(y)[..., None] + s[..., None] * lx + c[..., None] * ly
    return np.stack([cx, cy], axis=-1)


def _penetration_depth(a: FloatArray, b: FloatArray) -> FloatArray:
    """Minimum translation distance separating overlapping boxes (separating axis theorem).

    For convex polygons the smallest overlap over all edge normals is the exact penetration depth.
    """
    edges = np.concatenate([np.roll(a, -1, axis=-2) - a, np.roll(b, -1, axis=-2) - b], axis=-2)
    normals = np.stack([-edges[..., 1], edges[..., 0]], axis=-1)
    normals /= np.linalg.norm(normals, axis=-1, keepdims=True)
    pa = np.einsum("...ck,...nk->...nc", a, normals)
    pb = np.einsum("...ck,...nk->...nc", b, normals)
    # the shortest push along an axis that separates the intervals, which exceeds their overlap
    # when one interval contains the other
    push = np.minimum(pa.max(-1) - pb.min(-1), pb.max(-1) - pa.min(-1))
    return push.min(axis=-1)


def signed_box_distance(corners_a: FloatArray, corners_b: FloatArray) -> FloatArray:
    """Gap between boxes when apart, minus the penetration depth when they overlap.

    Inputs broadcast as (..., 4, 2); the gap comes from shapely, the depth from SAT.
    """
    a, b = np.broadcast_arrays(np.asarray(corners_a, float), np.asarray(corners_b, float))
    if a.shape[:-2] == (0,) or a.size == 0:
        return np.zeros(a.shape[:-2])
    gap = shapely.distance(shapely.polygons(a), shapely.polygons(b))
    overlapping = gap <= 0.0
    out = np.asarray(gap, dtype=float)
    if np.any(overlapping):
        out = np.where(overlapping, -_penetration_depth(a, b), out)
    return out
