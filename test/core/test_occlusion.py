"""Low-fidelity occlusion against hand-computed arcs and scene invariances."""

import math

import numpy as np
import pytest

from advperc_ros.core.boxes import BoxSequence
from advperc_ros.core.occlusion import occlusion


def scene(boxes: list[tuple[float, float, float, float, float]]) -> BoxSequence:
    """One frame; boxes as (x, y, yaw, length, width)."""
    arr = np.array(boxes, dtype=float)
    frame = {"ids": np.arange(len(boxes)), "x": arr[:, 0], "y": arr[:, 1], "yaw": arr[:, 2], "length": arr[:, 3],
             "width": arr[:, 4], "height": np.full(len(boxes), 1.5), "vx": np.zeros(len(boxes)), "vy": np.zeros(len(boxes))}
    return BoxSequence.stack([frame])


ORIGIN = np.zeros((1, 2))


def test_a_car_hidden_behind_a_wider_closer_car_is_fully_occluded():
    occ = occlusion(scene([(10, 0, 0, 4, 2), (20, 0, 0, 4, 2)]), ORIGIN)[0]
    assert occ[0] == 0.0 and occ[1] == pytest.approx(1.0)


def test_cars_on_opposite_sides_do_not_occlude_each_other():
    occ = occlusion(scene([(10, 0, 0, 4, 2), (-20, 0, 0, 4, 2), (0, 15, 0, 4, 2)]), ORIGIN)[0]
    assert np.all(occ == 0.0)


def test_partial_cover_matches_the_arc_overlap_by_hand():
    # a thin wall at x = 10 spanning y in [0, 2] (length along y), a target at x = 20 spanning y in [-1, 1]
    near = (10.0, 1.0, math.pi / 2, 2.0, 0.01)
    far = (20.0, 0.0, math.pi / 2, 2.0, 0.01)
    occ = occlusion(scene([near, far]), ORIGIN)[0]
    wall = (math.atan2(0.0, 10.005), math.atan2(2.0, 10.005))
    target = (math.atan2(-1.0, 19.995), math.atan2(1.0, 19.995))
    expected = (min(wall[1], target[1]) - max(wall[0], target[0])) / (target[1] - target[0])
    assert occ[1] == pytest.approx(expected, abs=2e-3)
    assert occ[0] == 0.0


def test_wrap_around_behind_the_ego():
    occ = occlusion(scene([(-10, 0.01, 0, 4, 2), (-20, -0.01, 0, 4, 2)]), ORIGIN)[0]
    assert occ[1] == pytest.approx(1.0)


def test_rotating_and_translating_the_scene_changes_nothing():
    rng = np.random.default_rng(0)
    boxes = [(rng.uniform(-30, 30), rng.uniform(-30, 30), rng.uniform(-3, 3), 4.5, 1.9) for _ in range(8)]
    base = occlusion(scene(boxes), ORIGIN)[0]
    angle, offset = 0.7, np.array([5.0, -3.0])
    c, s = math.cos(angle), math.sin(angle)
    moved = [(c * x - s * y + offset[0], s * x + c * y + offset[1], yaw + angle, l, w) for x, y, yaw, l, w in boxes]
    np.testing.assert_allclose(occlusion(scene(moved), offset[None]), base[None], atol=1e-9)


def test_empty_slots_are_nan_and_the_ego_inside_a_box_sees_it_unoccluded():
    a = scene([(0, 0, 0, 4, 2), (10, 0, 0, 4, 2)])
    padded = BoxSequence.stack([a.frame(0), {k: v[:1] for k, v in a.frame(0).items()}])
    occ = occlusion(padded, np.zeros((2, 2)))
    assert occ[0, 0] == 0.0 and occ[0, 1] == pytest.approx(1.0)  # the box around the ego hides everything
    assert np.isnan(occ[1, 1])
