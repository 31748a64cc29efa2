"""Planar geometry shared by scenarios, planners and rules: polylines and oriented boxes."""

import math
from collections.abc import Sequence
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


def _norms(vectors: FloatArray) -> FloatArray:
    """The length of each vector (..., 2): np.linalg.norm's arithmetic along the last axis, to the bit, without
    its checks (a projection's hottest line)."""
    return np.sqrt(np.add.reduce(vectors * vectors, axis=-1))


@dataclass(frozen=True)
class Polyline:
    """A 2D path parameterised by arc length; the route and lane centrelines use it."""

    points: FloatArray  # (M, 2)
    # derived in __post_init__: unit direction of each segment (M-1, 2) and arc length of each vertex (M,)
    _seg_dir: FloatArray = field(init=False, repr=False, compare=False)
    _s: FloatArray = field(init=False, repr=False, compare=False)
    # how far along each segment a point's foot may lie: the end segments extend to infinity so that points past
    # the ends project onto them
    _low: FloatArray = field(init=False, repr=False, compare=False)
    _high: FloatArray = field(init=False, repr=False, compare=False)

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
        low, high = np.zeros(len(seg_len)), np.diff(self._s)
        low[0], high[-1] = -np.inf, np.inf
        object.__setattr__(self, "_low", low)
        object.__setattr__(self, "_high", high)

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
        along = np.einsum("...sk,sk->...s", rel, self._seg_dir)
        t = np.clip(along, self._low, self._high)
        foot = self.points[:-1] + t[..., None] * self._seg_dir
        dist = _norms(xy[..., None, :] - foot)
        best = np.argmin(dist, axis=-1)
        t_best = np.take_along_axis(t, best[..., None], axis=-1)[..., 0]
        s = self._s[best] + t_best
        d = self._seg_dir[best]
        rel_best = np.take_along_axis(rel, best[..., None, None], axis=-2)[..., 0, :]
        lateral = d[..., 0] * rel_best[..., 1] - d[..., 1] * rel_best[..., 0]
        return s, lateral


class Polylines:
    """Several polylines' segments held end to end, so that points project onto any of them in one numpy pass, each
    with `Polyline.project`'s arithmetic and `Polyline.heading`'s segment, to the bit. A frame that projects
    every track onto every lane of a recording (a hundred lanes) or every leader onto its follower's recorded
    path would otherwise pay a hundred small numpy passes; this pays one. `None` stands for a line that is not
    there (a parked agent's path): no point may be asked of it (`segments` 0)."""

    def __init__(self, lines: Sequence[Polyline | None]) -> None:
        present = [line for line in lines if line is not None]
        self.segments = np.array([0 if line is None else line.points.shape[0] - 1 for line in lines], dtype=int)
        self._first = np.concatenate([[0], np.cumsum(self.segments)[:-1]]).astype(int)  # each line's first segment
        self._starts = np.concatenate([line.points[:-1] for line in present] or [np.zeros((0, 2))])
        self._directions = np.concatenate([line._seg_dir for line in present] or [np.zeros((0, 2))])
        self._stations = np.concatenate([line.stations[:-1] for line in present] or [np.zeros(0)])  # segment starts
        self._low = np.concatenate([line._low for line in present] or [np.zeros(0)])
        self._high = np.concatenate([line._high for line in present] or [np.zeros(0)])
        self._line = np.repeat(np.arange(len(lines)), self.segments)  # each segment's line

    def __len__(self) -> int:
        return len(self.segments)

    def project(self, which: np.ndarray, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(arc length, signed lateral offset, unit direction of the segment `Polyline.heading` reads there) of each
        point `xy` (P, 2) on line `which` (P,): each the `Polyline.project` of that point on that line."""
        count = self.segments[which]
        offsets = np.arange(max(int(count.max(initial=0)), 1))
        padding = offsets[None, :] >= count[:, None]
        segment = np.where(padding, 0, self._first[which][:, None] + offsets[None, :])  # (P, S): the line's segments
        rel = xy[:, None, :] - self._starts[segment]
        directions = self._directions[segment]
        along = np.einsum("psk,psk->ps", rel, directions)
        t = np.clip(along, self._low[segment], self._high[segment])
        dist = _norms(xy[:, None, :] - (self._starts[segment] + t[..., None] * directions))
        dist[padding] = np.inf
        rows = np.arange(len(which))
        best = np.argmin(dist, axis=-1)
        s, lateral = self._station_and_offset(segment[rows, best], t[rows, best], rel[rows, best])
        return s, lateral, self.directions(which, s)

    def project_all(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(arc length, lateral offset) of every point `xy` (M, 2) on every line (none of them None), arrays (L, M):
        `project`'s, each point meeting every segment once, with no padding (`directions` gives the headings,
        for the pairs that need them)."""
        if not self.segments.all():
            raise ValueError("project_all needs every line: one of them is None")
        rel = xy[:, None, :] - self._starts  # (M, S, 2)
        along = np.einsum("msk,sk->ms", rel, self._directions)
        t = np.clip(along, self._low, self._high)
        dist = _norms(xy[:, None, :] - (self._starts + t[..., None] * self._directions))
        nearest = np.minimum.reduceat(dist, self._first, axis=1)  # (M, L)
        # the first segment of its line at that distance, as argmin takes it
        candidates = np.where(dist == nearest[:, self._line], np.arange(len(self._line)), len(self._line) - 1)
        best = np.minimum.reduceat(candidates, self._first, axis=1).T  # (L, M)
        points = np.broadcast_to(np.arange(len(xy)), best.shape)
        return self._station_and_offset(best, t[points, best], rel[points, best])

    def directions(self, lines: np.ndarray, s: np.ndarray) -> np.ndarray:
        """The unit direction (..., 2) of the segment `Polyline.heading` reads at arc length `s` on line `lines`
        (arrays of one shape): the last segment of the line starting at or before s."""
        first, count = self._first[lines], self.segments[lines]
        offsets = np.arange(max(int(self.segments.max(initial=0)), 1))
        within = first[..., None] + np.minimum(offsets, count[..., None] - 1)
        at_or_before = (self._stations[within] <= s[..., None]) & (offsets < count[..., None])
        return self._directions[first + np.clip(np.count_nonzero(at_or_before, axis=-1) - 1, 0, count - 1)]

    def _station_and_offset(self, best: np.ndarray, t: np.ndarray, rel: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(arc length, lateral offset) from each point's nearest segment `best` (of all lines' segments), its
        clipped position `t` along it and the point relative to the segment's start `rel`."""
        d = self._directions[best]
        return self._stations[best] + t, d[..., 0] * rel[..., 1] - d[..., 1] * rel[..., 0]


TURN_WINDOW = 2.0  # m of path over which a turn is measured: about a car's wheelbase


def _tight_turns(path: Polyline, window: float, limit: float) -> tuple[float, FloatArray]:
    """(the largest heading change over any `window` metres of the path, divided by the window; the
    (start, end) arc lengths of every stretch of at most `window` metres whose turn exceeds `limit`
    times the window). Exact for a polyline, whose heading changes only at its vertices: a window
    sees the turn from segment a to segment b when the vertices between them lie within it, so no
    sampling can miss a corner or shift the figure with where its samples fall."""
    heading = np.unwrap(np.arctan2(path._seg_dir[:, 1], path._seg_dir[:, 0]))  # per segment
    vertex = path._s  # vertex v joins segments v-1 and v
    sharpest, tight = 0.0, []
    for offset in range(1, len(heading)):
        a = np.arange(len(heading) - offset)  # segment pairs (a, a + offset)
        within = vertex[a + offset] - vertex[a + 1] <= window
        if not within.any():
            break
        turn = np.abs(heading[a + offset] - heading[a])
        sharpest = max(sharpest, float(np.max(turn[within])))
        over = within & (turn > limit * window)
        tight += [np.stack([vertex[a[over] + 1], vertex[a[over] + offset]], axis=1)]
    return sharpest / window, np.concatenate(tight) if tight else np.zeros((0, 2))


def sharpest_turn(path: Polyline, window: float = TURN_WINDOW) -> float:
    """The path's largest mean curvature (1/m) over any `window` metres of it: the heading's change
    within the window, divided by its length. A polyline's vertex turns in no length at all, so its
    pointwise curvature says nothing; over a car's length a turn of radius R averages to 1/R."""
    return _tight_turns(path, window, np.inf)[0]


PINNED = 1e4  # a smoothing spline's weight on the points away from tight turns (1 near them): they stay put
ANCHOR = 10.0  # m of pinned path fitted on either side of a stretch that is rounded, so that it joins the rest


def _least_smoothed(stations: FloatArray, points: FloatArray, weights: FloatArray, min_radius: float) -> FloatArray:
    """The points (K, 2) at `stations` of the least smoothed weighted cubic smoothing spline through
    `points` that turns no tighter than `min_radius`: its penalty bracketed, then bisected."""
    from scipy.interpolate import make_smoothing_spline  # only paths with tight turns need it

    def smoothed(penalty: float) -> FloatArray:
        return np.stack([make_smoothing_spline(stations, points[:, axis], w=weights, lam=penalty)(stations)
                         for axis in (0, 1)], axis=1)

    def too_tight(penalty: float) -> bool:
        return sharpest_turn(Polyline(smoothed(penalty))) > 1.0 / min_radius

    low, high = 0.0, 1.0
    while too_tight(high):
        low, high = high, 16.0 * high
        if high > 1e12:
            raise ValueError(f"no smoothing of the path turns no tighter than a {min_radius:g} m radius")
    for _ in range(40):  # the penalty to 2^-40 of its bracket
        middle = 0.5 * (low + high)
        low, high = (middle, high) if too_tight(middle) else (low, middle)
    return smoothed(high)


def round_corners(path: Polyline, min_radius: float, spacing: float = 0.5) -> Polyline:
    """`path` itself where no `TURN_WINDOW` of it turns tighter than `min_radius` (`sharpest_turn`),
    else the path with each stretch within two radii of a tight turn (as points `spacing` apart)
    replaced by the least smoothed cubic smoothing spline through it (scipy's
    `make_smoothing_spline`, x and y over arc length, its penalty found by bisection) that turns no
    tighter. The spline is fitted over the stretch and `ANCHOR` metres either side, those weighing
    `PINNED`: a turn of that radius needs less room than two radii, so the corners are rounded and
    the rest stays where it was (a path smoothed as a whole moves everywhere, its ends too), and the
    cost grows with the corners, not with the path's length. Outside the stretches the path keeps
    its own vertices: a planner projects onto the route every frame, at a cost per vertex. It cuts
    a right angle about 1.5 times as deep as the circular fillet, the least any curve of that
    radius can (test_geometry.py).
    Raises ValueError where no such spline exists (a path turning back on itself)."""
    limit = 1.0 / min_radius
    _, tight = _tight_turns(path, TURN_WINDOW, limit)
    if len(tight) == 0:
        return path
    stations = np.linspace(0.0, path.length, int(math.ceil(path.length / spacing)) + 1)
    points = path.position(stations)
    reach = 2.0 * min_radius
    near = np.zeros(len(stations), bool)
    for first, last in tight:
        near[np.searchsorted(stations, first - reach):np.searchsorted(stations, last + reach, side="right")] = True
    edges = np.flatnonzero(np.diff(np.concatenate([[0], near.view(np.int8), [0]])))
    starts, stops = list(edges[::2]), list(edges[1::2])  # each stretch near tight turns, [start, stop)
    for i in range(len(starts) - 1, 0, -1):  # stretches whose anchors overlap are fitted as one
        if stations[starts[i]] - stations[stops[i - 1] - 1] <= 2.0 * ANCHOR:
            del starts[i], stops[i - 1]
    pieces, done = [], 0.0  # the path's own vertices between the stretches, the splines' points in them
    for first, stop in zip(starts, stops):
        lo = np.searchsorted(stations, stations[first] - ANCHOR)
        hi = np.searchsorted(stations, stations[stop - 1] + ANCHOR, side="right")
        fitted = _least_smoothed(stations[lo:hi], points[lo:hi], np.where(near[lo:hi], 1.0, PINNED), min_radius)
        pieces += [path.points[(path.stations >= done) & (path.stations < stations[first])], fitted[first - lo:stop - lo]]
        done = stations[stop - 1]
    pieces.append(path.points[path.stations > done])
    rounded = Polyline(np.concatenate(pieces))
    if sharpest_turn(rounded) > limit:  # where a rounded stretch meets the pinned path
        raise ValueError(f"no smoothing of the path turns no tighter than a {min_radius:g} m radius")
    return rounded


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
