"""Polyline, oriented boxes and the signed box distance, against hand-computed and independent references."""

import functools
import itertools
import math

import numpy as np
import pytest
import shapely
from hypothesis import given, settings
from hypothesis import strategies as st

from advperc_ros.core.geometry import (
    Polyline,
    Polylines,
    box_corners,
    round_corners,
    sharpest_turn,
    signed_box_distance,
    wrap_angle,
)

# An L: east 10 m from the origin, then north 10 m.  Arc length 0..10 on the first leg, 10..20 on the second.
L_SHAPE = Polyline(np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 10.0]]))


# ---------------------------------------------------------------- Polyline

def test_length_and_stations():
    assert L_SHAPE.length == pytest.approx(20.0)
    np.testing.assert_allclose(L_SHAPE.stations, [0.0, 10.0, 20.0])


def test_duplicate_points_are_dropped_and_degenerate_lines_rejected():
    line = Polyline(np.array([[0.0, 0.0], [0.0, 0.0], [3.0, 4.0]]))
    assert line.length == pytest.approx(5.0)
    with pytest.raises(ValueError):
        Polyline(np.array([[1.0, 1.0], [1.0, 1.0]]))


@pytest.mark.parametrize(
    "s, xy, heading",
    [
        (0.0, (0.0, 0.0), 0.0),
        (5.0, (5.0, 0.0), 0.0),
        (10.0, (10.0, 0.0), math.pi / 2),  # the vertex belongs to the second leg
        (15.0, (10.0, 5.0), math.pi / 2),
        (20.0, (10.0, 10.0), math.pi / 2),
        (-3.0, (-3.0, 0.0), 0.0),  # before the start: the first leg extended backwards
        (25.0, (10.0, 15.0), math.pi / 2),  # past the end: the last leg extended
    ],
)
def test_position_and_heading_on_l_shape(s, xy, heading):
    np.testing.assert_allclose(L_SHAPE.position(s), xy, atol=1e-12)
    assert float(L_SHAPE.heading(s)) == pytest.approx(heading, abs=1e-12)


def test_position_and_heading_vectorised():
    s = np.array([[2.0, 12.0], [-1.0, 30.0]])
    pos = L_SHAPE.position(s)
    assert pos.shape == (2, 2, 2)
    np.testing.assert_allclose(pos, [[[2.0, 0.0], [10.0, 2.0]], [[-1.0, 0.0], [10.0, 20.0]]], atol=1e-12)
    np.testing.assert_allclose(L_SHAPE.heading(s), [[0.0, math.pi / 2], [0.0, math.pi / 2]], atol=1e-12)


@pytest.mark.parametrize(
    "xy, s, lateral",
    [
        ((5.0, 2.0), 5.0, 2.0),  # left of the eastbound leg
        ((5.0, -2.0), 5.0, -2.0),  # right of it
        ((12.0, 5.0), 15.0, -2.0),  # east of the northbound leg is its right
        ((9.0, 3.0), 13.0, 1.0),  # inside the L, nearer the second leg
        ((8.0, 1.0), 8.0, 1.0),  # inside the L, nearer the first leg
        ((-3.0, 1.0), -3.0, 1.0),  # before the start
        ((-7.0, -0.5), -7.0, -0.5),
        ((10.5, 14.0), 24.0, -0.5),  # past the end
        ((9.0, 25.0), 35.0, 1.0),
    ],
)
def test_project_on_l_shape(xy, s, lateral):
    got_s, got_lat = L_SHAPE.project(np.array(xy))
    assert float(got_s) == pytest.approx(s, abs=1e-12)
    assert float(got_lat) == pytest.approx(lateral, abs=1e-12)


def test_project_is_inverse_of_position_with_offset():
    """A point placed at arc length s and lateral offset d (inside the no-ambiguity region) projects back."""
    rng = np.random.default_rng(3)
    s = np.concatenate([rng.uniform(-20.0, 8.0, 50), rng.uniform(12.0, 40.0, 50)])
    d = rng.uniform(-1.5, 1.5, s.size)
    h = L_SHAPE.heading(s)
    xy = L_SHAPE.position(s) + d[:, None] * np.stack([-np.sin(h), np.cos(h)], axis=1)
    got_s, got_d = L_SHAPE.project(xy)
    assert got_s.shape == (100,)
    np.testing.assert_allclose(got_s, s, atol=1e-9)
    np.testing.assert_allclose(got_d, d, atol=1e-9)


# ---------------------------------------------------------------- Polylines

# vertices and points on a coarse grid, so that a point is often as near two segments as each other (a tie that
# must go to the first, as argmin takes it) or lies on a vertex, beyond an end or on a segment's line
_GRID = st.integers(-4, 4).map(float)
_LINE = st.lists(st.tuples(_GRID, _GRID), min_size=2, max_size=6).filter(
    lambda points: any(a != b for a, b in itertools.pairwise(points)))


@settings(max_examples=200, deadline=None)
@given(lines=st.lists(_LINE, min_size=1, max_size=5),
       points=st.lists(st.tuples(st.integers(-12, 12).map(lambda v: v / 2.0), st.integers(-12, 12).map(lambda v: v / 2.0)),
                       min_size=1, max_size=12))
def test_polylines_project_each_point_as_its_polyline_does_to_the_bit(lines, points):
    """Polylines.project_all (every point on every line) with Polylines.directions, and Polylines.project (a point
    on a line of its own) give Polyline.project's arc length and lateral offset and Polyline.heading's direction,
    the same floats: the ObP planner and reactive traffic read them where one line at a time was read before."""
    polylines = [Polyline(np.array(line)) for line in lines]
    xy = np.array(points)
    bundle = Polylines(polylines)
    s, lateral = bundle.project_all(xy)
    assert s.shape == lateral.shape == (len(lines), len(points))
    direction = bundle.directions(np.broadcast_to(np.arange(len(lines))[:, None], s.shape), s)
    assert direction.shape == (len(lines), len(points), 2)
    which = np.arange(len(points)) % len(lines)
    s_one, lateral_one, direction_one = bundle.project(which, xy)
    for i, line in enumerate(polylines):
        expected_s, expected_lateral = line.project(xy)
        assert s[i].tolist() == expected_s.tolist()
        assert lateral[i].tolist() == expected_lateral.tolist()
        assert np.arctan2(direction[i, :, 1], direction[i, :, 0]).tolist() == line.heading(expected_s).tolist()
        mine = which == i
        assert s_one[mine].tolist() == expected_s[mine].tolist()
        assert lateral_one[mine].tolist() == expected_lateral[mine].tolist()
        assert direction_one[mine].tolist() == direction[i, mine].tolist()


def test_polylines_with_a_missing_line_project_onto_the_others_and_refuse_all():
    """A parked agent has no path (None): points go to the other lines, and projecting onto every line is refused."""
    bundle = Polylines([None, L_SHAPE])
    assert bundle.segments.tolist() == [0, 2]
    s, lateral, _ = bundle.project(np.array([1]), np.array([[5.0, 1.0]]))
    assert (s[0], lateral[0]) == (5.0, 1.0)
    with pytest.raises(ValueError, match="None"):
        bundle.project_all(np.zeros((1, 2)))


# ---------------------------------------------------------------- wrap_angle

def _circle_through(a, b, c):
    """Radius of the circle through three points (the circumradius: |ab| |bc| |ca| / (4 area))."""
    area = abs((b[0] - a[0]) * (c[1] - a[1]) - (c[0] - a[0]) * (b[1] - a[1])) / 2.0
    sides = np.linalg.norm(b - a) * np.linalg.norm(c - b) * np.linalg.norm(a - c)
    return math.inf if area < 1e-12 else sides / (4.0 * area)


def test_sharpest_turn_is_one_over_the_radius_of_an_arc():
    arc = Polyline(8.0 * np.stack([np.cos(np.linspace(0, 1.5, 600)), np.sin(np.linspace(0, 1.5, 600))], axis=1))
    assert sharpest_turn(arc) == pytest.approx(1.0 / 8.0, rel=1e-2)  # the chords' own turns: 2.5 mrad each
    assert sharpest_turn(L_SHAPE) == pytest.approx((math.pi / 2) / 2.0)  # the vertex's quarter turn within 2 m


def test_sharpest_turn_does_not_depend_on_where_a_path_has_its_vertices():
    """The same path with collinear vertices added along its legs, or begun 0.37 m earlier on the
    same line, turns as sharply: the measure sees each corner whole, not as samples fall."""
    corner = np.array([[0.0, 0.0], [10.0, 0.0], [11.0, 0.6], [20.0, 4.0]])
    denser = np.array([[0.0, 0.0], [3.3, 0.0], [7.1, 0.0], [10.0, 0.0], [11.0, 0.6], [15.5, 2.3], [20.0, 4.0]])
    earlier = np.vstack([[[-0.37, 0.0]], corner[1:]])
    turns = [sharpest_turn(Polyline(points)) for points in (corner, denser, earlier)]
    assert turns[0] == pytest.approx(math.atan2(0.6, 1.0) / 2.0)  # the first vertex's turn, the second's turning back
    assert turns[1] == turns[0] and turns[2] == turns[0]


def test_a_path_that_turns_back_on_itself_cannot_be_rounded():
    hairpin = Polyline(np.array([[0.0, 0.0], [100.0, 0.0], [180.0, 3.0], [120.0, 0.0], [300.0, 0.0]]))
    with pytest.raises(ValueError, match="no smoothing"):
        round_corners(hairpin, 5.0)


def test_a_path_that_turns_no_tighter_than_the_radius_is_left_as_it_is():
    gentle = Polyline(np.array([[0.0, 0.0], [20.0, 0.0], [40.0, 1.0], [60.0, 3.0]]))
    assert round_corners(gentle, 5.0) is gentle


@pytest.mark.parametrize("radius", [5.0, 8.0])
def test_a_right_angle_is_rounded_to_the_radius_near_the_smallest_fillet(radius):
    """Every circle through three points 1 m apart on the rounded L is at least the radius (to the
    sampling's precision); the corner is cut by at least the circular fillet's R (sqrt 2 - 1), the
    least any curve of that radius can cut it, and at most 60 % more; more than two radii (and the
    window) from the corner nothing moves by as much as 5 mm."""
    corner = np.array([40.0, 0.0])
    long_l = Polyline(np.array([[0.0, 0.0], corner, [40.0, 40.0]]))
    rounded = round_corners(long_l, radius)
    assert sharpest_turn(rounded) <= 1.0 / radius + 1e-9
    s = np.arange(0.0, rounded.length - 2.0, 0.25)
    radii = [_circle_through(*rounded.position(np.array([a, a + 1.0, a + 2.0]))) for a in s]
    assert min(radii) >= 0.97 * radius
    cut = float(np.min(np.linalg.norm(rounded.points - corner, axis=1)))
    fillet = radius * (math.sqrt(2.0) - 1.0)
    assert fillet <= cut <= 1.6 * fillet
    _, lateral = long_l.project(rounded.points)
    far = np.max(np.abs(rounded.points - corner), axis=1) > 2.0 * radius + 4.0
    assert np.all(np.abs(lateral[far]) < 5e-3)


def test_wrap_angle_range_and_equivalence():
    a = np.concatenate([np.linspace(-50.0, 50.0, 10001), [np.pi, -np.pi, 3 * np.pi, 0.0]])
    w = wrap_angle(a)
    assert np.all(w >= -np.pi) and np.all(w < np.pi)
    # same angle: the difference is a multiple of 2 pi
    k = (a - w) / (2 * np.pi)
    np.testing.assert_allclose(k, np.round(k), atol=1e-9)
    assert float(wrap_angle(np.pi)) == pytest.approx(-np.pi)
    assert float(wrap_angle(0.3)) == pytest.approx(0.3)
    assert float(wrap_angle(-0.3 - 4 * np.pi)) == pytest.approx(-0.3)


def test_wrap_angle_of_a_float_is_a_float_equal_to_numpys_to_the_bit():
    rng = np.random.default_rng(1)
    angles = np.concatenate([rng.uniform(-50.0, 50.0, 20000), rng.normal(0.0, 1e-3, 1000), np.arange(-8, 9) * np.pi,
                             [np.pi, -np.pi, 3 * np.pi, np.nextafter(np.pi, 0.0), np.nextafter(-np.pi, 0.0), 0.0, -0.0]])
    wrapped = wrap_angle(angles)
    for angle, expected in zip(angles.tolist(), wrapped.tolist()):
        got = wrap_angle(angle)
        assert type(got) is float
        assert got == expected and np.signbit(got) == np.signbit(expected), angle


# ---------------------------------------------------------------- boxes

def test_box_corners_counter_clockwise_and_sized():
    c = box_corners(np.array(1.0), np.array(2.0), np.array(np.pi / 2), 4.0, 2.0)
    # length along +y after a quarter turn: x spans 1 +- 1, y spans 2 +- 2
    np.testing.assert_allclose(np.sort(c[:, 0]), [0.0, 0.0, 2.0, 2.0], atol=1e-12)
    np.testing.assert_allclose(np.sort(c[:, 1]), [0.0, 0.0, 4.0, 4.0], atol=1e-12)
    poly = shapely.Polygon(c)
    assert poly.area == pytest.approx(8.0)
    assert poly.exterior.is_ccw


def _random_boxes(rng, n):
    return (
        rng.uniform(-1.0, 1.0, n),
        rng.uniform(-1.0, 1.0, n),
        rng.uniform(-np.pi, np.pi, n),
        rng.uniform(1.0, 5.0, n),
        rng.uniform(0.5, 2.5, n),
    )


def _segment_point_distance(p, a, b):
    ab = b - a
    t = np.clip(np.dot(p - a, ab) / np.dot(ab, ab), 0.0, 1.0)
    return np.linalg.norm(p - (a + t * ab))


def _naive_gap(ca, cb):
    """Distance of two disjoint convex polygons: the minimum vertex-to-edge distance either way."""
    best = np.inf
    for p_set, q_set in ((ca, cb), (cb, ca)):
        for p in p_set:
            for i in range(4):
                best = min(best, _segment_point_distance(p, q_set[i], q_set[(i + 1) % 4]))
    return best


def test_gap_of_separated_boxes_matches_shapely_and_naive_reference():
    rng = np.random.default_rng(11)
    x, y, yaw, length, width = _random_boxes(rng, 200)
    a = box_corners(x, y, yaw, length, width)
    angle = rng.uniform(0, 2 * np.pi, 200)
    dist = rng.uniform(4.0, 12.0, 200)
    b = box_corners(x + dist * np.cos(angle), y + dist * np.sin(angle), rng.uniform(-np.pi, np.pi, 200),
                    rng.uniform(1.0, 5.0, 200), rng.uniform(0.5, 2.5, 200))
    got = signed_box_distance(a, b)
    assert got.shape == (200,)
    ref = np.array([shapely.Polygon(pa).distance(shapely.Polygon(pb)) for pa, pb in zip(a, b)])
    naive = np.array([_naive_gap(pa, pb) for pa, pb in zip(a, b)])
    separated = ref > 1e-6
    assert separated.sum() > 150  # the sample mostly contains separated boxes
    np.testing.assert_allclose(got[separated], ref[separated], rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(got[separated], naive[separated], rtol=1e-9, atol=1e-9)
    # symmetric in its arguments
    np.testing.assert_allclose(signed_box_distance(b, a)[separated], got[separated], atol=1e-12)


def _minkowski_signed_distance(ca, cb):
    """Signed distance from shapely alone: b touches a when translated by a point of the Minkowski
    difference a - b, so the distance from the origin to that polygon's boundary is the gap (origin
    outside) or the penetration depth (origin inside)."""
    hull = shapely.MultiPoint((ca[:, None, :] - cb[None, :, :]).reshape(-1, 2)).convex_hull
    origin = shapely.Point(0.0, 0.0)
    return -hull.exterior.distance(origin) if hull.contains(origin) else hull.distance(origin)


def test_signed_distance_equals_shapely_on_random_boxes_overlapping_and_apart():
    rng = np.random.default_rng(23)
    n = 2000
    x, y, yaw, length, width = _random_boxes(rng, n)
    a = box_corners(x, y, yaw, length, width)
    # centres 0 to 8 m apart: deep overlaps, shallow ones, near misses and clear gaps
    angle, dist = rng.uniform(0.0, 2.0 * np.pi, n), rng.uniform(0.0, 8.0, n)
    b = box_corners(x + dist * np.cos(angle), y + dist * np.sin(angle), *_random_boxes(rng, n)[2:])
    got = signed_box_distance(a, b)
    ref = np.array([_minkowski_signed_distance(pa, pb) for pa, pb in zip(a, b)])
    apart = shapely.distance(shapely.polygons(a), shapely.polygons(b))
    np.testing.assert_allclose(got, ref, rtol=0.0, atol=1e-9)
    np.testing.assert_allclose(got[apart > 0.0], apart[apart > 0.0], rtol=0.0, atol=1e-9)
    assert np.all(got[apart == 0.0] <= 0.0)
    assert (got < -0.1).sum() > 300 and (got > 0.1).sum() > 300 and (np.abs(got) < 0.1).sum() > 20


def test_broadcast_one_box_against_many_and_empty():
    ego = box_corners(0.0, 0.0, 0.0, 4.0, 2.0)
    others = box_corners(np.array([10.0, 0.0, 0.0]), np.array([0.0, 5.0, 0.0]), np.zeros(3), 4.0, 2.0)
    got = signed_box_distance(ego[None], others)
    np.testing.assert_allclose(got, [6.0, 3.0, -2.0], atol=1e-12)  # identical boxes: depth = width
    assert signed_box_distance(np.zeros((0, 4, 2)), np.zeros((0, 4, 2))).shape == (0,)


def _separation_along(a_poly, b_corners, directions, t_hi, iterations=32):
    """Per direction, the smallest translation of b along it after which a and b no longer intersect.

    For convex a and b the translations that keep them intersecting form an interval containing 0,
    so bisection on `intersects` finds its upper end."""
    lo = np.zeros(len(directions))
    hi = np.full(len(directions), t_hi)
    for _ in range(iterations):
        mid = 0.5 * (lo + hi)
        moved = shapely.polygons(b_corners[None] + mid[:, None, None] * directions[:, None, :])
        hit = shapely.intersects(a_poly, moved)
        lo = np.where(hit, mid, lo)
        hi = np.where(hit, hi, mid)
    return hi


def _sweep_directions(a, b):
    """A sweep of directions every half degree, plus the edge normals of both boxes, among which the
    optimum of two convex polygons lies (the separating axis theorem), so it is in the set."""
    theta = np.linspace(0.0, 2 * np.pi, 720, endpoint=False)
    edges = np.concatenate([np.roll(a, -1, axis=0) - a, np.roll(b, -1, axis=0) - b])
    normal_angles = np.arctan2(edges[:, 0], -edges[:, 1])
    theta = np.concatenate([theta, normal_angles, normal_angles + np.pi])
    return np.stack([np.cos(theta), np.sin(theta)], axis=1)


def _check_depth_is_minimum_translation(a, b):
    result = float(signed_box_distance(a, b))
    assert result < 0.0
    depth = -result
    directions = _sweep_directions(a, b)
    a_poly = shapely.Polygon(a)
    needed = _separation_along(a_poly, b, directions, t_hi=20.0)
    best = int(np.argmin(needed))
    # the smallest separating translation over all directions is the depth
    assert needed[best] == pytest.approx(depth, abs=1e-3)
    # translating by slightly more than the depth along SOME direction separates ...
    moved = shapely.polygons(b[None] + depth * (1 + 1e-6) * directions[:, None, :])
    assert np.any(~shapely.intersects(a_poly, moved))
    # ... and translating by 0.99 of the depth never does, whatever the direction
    shrunk = shapely.polygons(b[None] + 0.99 * depth * directions[:, None, :])
    assert np.all(shapely.area(shapely.intersection(a_poly, shrunk)) > 0.0)
    # the depth is symmetric in the two boxes
    assert float(signed_box_distance(b, a)) == pytest.approx(result, abs=1e-9)


def _car_box(rng, x=0.0, y=0.0):
    return box_corners(x, y, rng.uniform(-np.pi, np.pi), rng.uniform(3.5, 5.0), rng.uniform(1.6, 2.1))


@functools.lru_cache(maxsize=None)
def _shallow_pairs(count=10, seed=5):
    """Car-sized boxes brought into contact along a random direction, then pushed 2..50 cm further in:
    the kind of overlap a rollout sees at its first collision frame."""
    rng = np.random.default_rng(seed)
    pairs = []
    for _ in range(count):
        a = _car_box(rng)
        b_far = _car_box(rng)
        u = rng.normal(size=2)
        u /= np.linalg.norm(u)
        start = b_far + 20.0 * u  # far away along u
        # bring b back along -u until it touches a
        lo, hi = 0.0, 20.0  # distance moved back from `start` towards a
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            if shapely.Polygon(a).intersects(shapely.Polygon(start - mid * u)):
                hi = mid
            else:
                lo = mid
        push = rng.uniform(0.02, 0.5)
        pairs.append((a, start - (hi + push) * u))
    return pairs


@pytest.mark.parametrize("case", range(10))
def test_shallow_penetration_depth_is_the_minimum_translation(case):
    a, b = _shallow_pairs()[case]
    _check_depth_is_minimum_translation(a, b)


def _deep_pairs(count=12, seed=5):
    """Random boxes of unequal size with heavily overlapping centres (one often inside the other along an axis)."""
    rng = np.random.default_rng(seed)
    pairs = []
    while len(pairs) < count:
        xa, ya, yawa, la, wa = (v[0] for v in _random_boxes(rng, 1))
        xb, yb, yawb, lb, wb = (v[0] for v in _random_boxes(rng, 1))
        a = box_corners(xa, ya, yawa, la, wa)
        b = box_corners(xb, yb, yawb, lb, wb)
        if shapely.Polygon(a).intersection(shapely.Polygon(b)).area > 1e-3:
            pairs.append((a, b))
    return pairs


def test_deep_penetration_depth_is_the_minimum_translation():
    for a, b in _deep_pairs():
        _check_depth_is_minimum_translation(a, b)


def test_depth_of_box_inside_box():
    big = box_corners(0.0, 0.0, 0.0, 4.0, 2.0)
    small = box_corners(0.0, 0.0, 0.0, 1.0, 1.0)
    # leaving along +-y needs 1 + 0.5 = 1.5 m, along +-x 2 + 0.5 = 2.5 m
    assert float(signed_box_distance(big, small)) == pytest.approx(-1.5, abs=1e-9)


def test_depth_of_box_inside_box_is_still_a_violation():
    """Whatever its magnitude, containment is an overlap: the sign must be negative."""
    big = box_corners(0.0, 0.0, 0.0, 4.0, 2.0)
    small = box_corners(0.3, -0.2, 0.4, 1.0, 1.0)
    assert float(signed_box_distance(big, small)) < -0.4


def test_depth_of_axis_aligned_overlap_is_smaller_overlap_extent():
    a = box_corners(0.0, 0.0, 0.0, 4.0, 2.0)
    b = box_corners(3.5, 0.5, 0.0, 4.0, 2.0)  # overlap 0.5 m in x, 1.5 m in y
    assert float(signed_box_distance(a, b)) == pytest.approx(-0.5, abs=1e-12)
    c = box_corners(0.3, 1.6, 0.0, 4.0, 2.0)  # overlap 3.7 m in x, 0.4 m in y
    assert float(signed_box_distance(a, c)) == pytest.approx(-0.4, abs=1e-12)


@pytest.mark.parametrize("yaw", [0.0, 0.3, 1.0, -2.2])
def test_touching_boxes_give_zero(yaw):
    d = np.array([np.cos(yaw), np.sin(yaw)])
    n = np.array([-np.sin(yaw), np.cos(yaw)])
    a = box_corners(1.0, -2.0, yaw, 4.0, 2.0)
    end_to_end = box_corners(1.0 + 4.0 * d[0], -2.0 + 4.0 * d[1], yaw, 4.0, 2.0)
    side_by_side = box_corners(1.0 + 2.0 * n[0] + 1.0 * d[0], -2.0 + 2.0 * n[1] + 1.0 * d[1], yaw, 4.0, 2.0)
    assert abs(float(signed_box_distance(a, end_to_end))) < 1e-9
    assert abs(float(signed_box_distance(a, side_by_side))) < 1e-9
