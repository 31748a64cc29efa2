"""A requirement's error space (`core.perception_errors.restriction`): every kind's projection keeps only that
kind's errors, only on the object-frames in the distance bin, none larger than the magnitude, and leaves a
tensor already inside alone; the distance bin is measured from the ego's centre."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from advperc_ros.core.perception_errors import ERROR_KINDS, PerceptionErrors
from advperc_ros.core.perception_errors.restriction import MAGNITUDES, Restriction, Scene, distance_mask

DT = 0.1


def scene(within: np.ndarray, seed: int = 0) -> Scene:
    """Cars anywhere, at any heading, and an ego anywhere, with `within` the object-frames in the bin."""
    rng = np.random.default_rng(seed)
    frames, agents = within.shape
    return Scene(within, rng.uniform(-50, 50, within.shape), rng.uniform(-50, 50, within.shape),
                 rng.uniform(-math.pi, math.pi, within.shape), rng.uniform(-50, 50, (frames, 2)), DT)


GHOSTS = 3  # ghost slots per frame


def random_errors(seed: int, frames: int = 30, agents: int = 4) -> PerceptionErrors:
    """Errors of every kind at once, large and everywhere (ghosts on in half the slot-frames, anywhere)."""
    rng = np.random.default_rng(seed)
    errors = PerceptionErrors.none(frames, agents, tuple(ERROR_KINDS), GHOSTS)
    arrays = errors.arrays()
    arrays["fn"][:] = rng.random((frames, agents)) < 0.5
    arrays["ghost_on"][:] = rng.random((frames, GHOSTS)) < 0.5
    for name in ("ghost_x", "ghost_y"):
        arrays[name][:] = rng.uniform(-50, 50, (frames, GHOSTS))
    for name in ("ghost_yaw", "ghost_vx", "ghost_vy"):
        arrays[name][:] = rng.normal(0.0, 3.0, (frames, GHOSTS))
    for name in ("dx", "dy", "dyaw", "dvx", "dvy"):
        arrays[name][:] = rng.normal(0.0, 3.0, (frames, agents))
    for name in ("length_scale", "width_scale"):
        arrays[name][:] = np.exp(rng.normal(0.0, 0.7, (frames, agents)))
    arrays["latency"][:] = rng.integers(0, 10, (frames, agents))
    return errors


@settings(max_examples=60, deadline=None)
# magnitudes of a requirement: 0, or from a micrometre (a subnormal float's products underflow, which no bound is)
@given(seed=st.integers(0, 10_000), kind=st.sampled_from(sorted(MAGNITUDES)),
       magnitude=st.one_of(st.just(0.0), st.floats(1e-6, 5.0)),
       mask_seed=st.integers(0, 10_000))
def test_a_projection_keeps_one_kind_in_its_bin_and_bound(seed, kind, magnitude, mask_seed):
    errors = random_errors(seed)
    within = np.random.default_rng(mask_seed).random(errors.shape) < 0.6
    view = scene(within, mask_seed)
    near, far = 10.0, 60.0  # the bin `within` stands for; a ghost's own distance decides its
    ghost_within = np.hypot(errors.ghost_x - view.ego_xy[:, :1], errors.ghost_y - view.ego_xy[:, 1:2])
    ghost_within = (ghost_within >= near) & (ghost_within < far)
    out = Restriction(kind, magnitude, near, far).project(errors, view)
    blank = PerceptionErrors.none(*errors.shape, errors.kinds, errors.ghost_slots).arrays()
    own = {"drop": ("fn",), "position": ("dx", "dy"), "yaw": ("dyaw",), "velocity": ("dvx", "dvy"),
           "size": ("length_scale", "width_scale"), "latency": ("latency",),
           "ghost": ("ghost_on", "ghost_x", "ghost_y", "ghost_yaw", "ghost_vx", "ghost_vy")}[kind]
    for name, array in out.arrays().items():
        if name not in own:
            assert np.array_equal(array, blank[name]), name  # every other kind perceived perfectly
        else:
            outside = ~ghost_within if kind == "ghost" else ~within
            assert np.array_equal(array[outside], blank[name][outside]), name  # nothing outside the bin
    frames = math.floor(magnitude / DT + 1e-9)
    arrays = out.arrays()
    if kind == "drop":
        assert (arrays["fn"].sum(axis=0) <= frames).all()
        assert not (arrays["fn"] & ~errors.fn).any()  # only misses the tensor had
    elif kind in ("position", "velocity"):
        a, b = own
        assert (np.hypot(arrays[a], arrays[b]) <= magnitude * (1 + 1e-9) + 1e-12).all()
    elif kind == "yaw":
        assert (np.abs(arrays["dyaw"]) <= magnitude + 1e-12).all()
    elif kind == "size":
        for name in own:
            assert ((arrays[name] >= 1.0 / (1.0 + magnitude) - 1e-12) & (arrays[name] <= 1.0 + magnitude + 1e-12)).all()
    elif kind == "latency":
        assert (arrays["latency"] <= frames).all()
    else:
        assert arrays["ghost_on"].sum() <= frames and not (arrays["ghost_on"] & ~errors.ghost_on).any()
        for name in own[1:]:  # a ghost kept is the ghost proposed, where it stood
            assert np.array_equal(arrays[name][arrays["ghost_on"]], getattr(errors, name)[arrays["ghost_on"]])
    again = Restriction(kind, magnitude, near, far).project(out, view)  # inside already: left alone
    assert all(np.array_equal(x, y) for x, y in zip(again.arrays().values(), arrays.values()))


def test_a_drop_keeps_a_car_s_first_missed_frames_however_they_are_spread():
    """Spread misses add up: hiding a car again and again with a frame of it between is one long miss to a
    tracker that deletes tracks at once."""
    errors = PerceptionErrors.none(12, 1)
    errors.fn[[0, 1, 3, 4, 6, 7, 9], 0] = True
    out = Restriction("drop", 0.45).project(errors, scene(np.ones((12, 1), bool)))
    assert np.flatnonzero(out.fn[:, 0]).tolist() == [0, 1, 3, 4]


def test_position_keeps_its_direction_and_yaw_its_sign():
    errors = PerceptionErrors.none(1, 2)
    errors.dx[0], errors.dy[0], errors.dyaw[0] = [3.0, 0.3], [4.0, 0.4], [-0.5, 0.2]
    out = Restriction("position", 1.0).project(errors, scene(np.ones((1, 2), bool)))
    assert out.dx[0].tolist() == pytest.approx([0.6, 0.3]) and out.dy[0].tolist() == pytest.approx([0.8, 0.4])
    assert Restriction("yaw", 0.3).project(errors, scene(np.ones((1, 2), bool))).dyaw[0].tolist() == [-0.3, 0.2]


def test_a_missed_car_is_shown_as_far_sideways_away_from_the_ego_as_the_bound_allows():
    """The lead 20 m ahead heading east with the ego behind and a touch to its left; a car on the ego's right
    heading north. Missed, each is shown 1.5 m off across its heading on the side away from the ego, and, under
    a velocity requirement, moving 1.5 m/s faster away from the ego along its heading."""
    errors = PerceptionErrors.none(1, 2, ("velocity",))
    errors.fn[0] = True
    view = Scene(np.ones((1, 2), bool), np.array([[20.0, 5.0]]), np.array([[0.0, -10.0]]),
                 np.array([[0.0, math.pi / 2]]), np.array([[0.0, 0.1]]), DT)
    out = Restriction("position", 1.5).project(errors, view)
    assert not out.fn.any()
    assert out.dx[0].tolist() == pytest.approx([0.0, 1.5], abs=1e-12)  # north-heading car: east, away from the ego
    assert out.dy[0].tolist() == pytest.approx([-1.5, 0.0], abs=1e-12)  # the lead: south, away from the ego
    fast = Restriction("velocity", 1.5).project(errors, view)
    assert fast.dvx[0].tolist() == pytest.approx([1.5, 0.0], abs=1e-12)
    assert fast.dvy[0].tolist() == pytest.approx([0.0, -1.5], abs=1e-12)  # heading north, the ego north of it


def test_the_distance_bin_is_measured_from_the_ego_s_centre_at_each_frame():
    x = np.array([[10.0, 30.0], [10.0, 30.0], [10.0, 30.0]])
    y = np.zeros_like(x)
    valid = np.array([[True, True], [True, True], [False, True]])
    ego = np.array([[0.0, 0.0], [15.0, 0.0]])  # two frames of rollout: the third counts as the second
    mask = distance_mask(x, y, valid, ego, 0.0, 20.0)
    assert mask.tolist() == [[True, False], [True, True], [False, True]]
    assert distance_mask(x, y, valid, ego, 20.0, math.inf).tolist() == [[False, True], [False, False], [False, False]]


def test_ghosts_are_bounded_by_their_time_in_all_and_by_where_they_stand():
    """Two slots; a ghost 10 m from the ego for frames 0-4 in slot 0, one 30 m away at frames 2-3 in slot 1.
    Within 20 m and 0.3 s, slot 0's first three frames stay; at 20-40 m, slot 1's two."""
    errors = PerceptionErrors.none(6, 1, ("ghost",), 2)
    errors.ghost_on[0:5, 0], errors.ghost_on[2:4, 1] = True, True
    errors.ghost_x[:, 0], errors.ghost_x[:, 1] = 10.0, 30.0
    view = scene(np.ones((6, 1), bool))
    view = Scene(view.within, view.x, view.y, view.yaw, np.zeros((6, 2)), DT)
    near_by = Restriction("ghost", 0.3, 0.0, 20.0).project(errors, view)
    assert np.flatnonzero(near_by.ghost_on[:, 0]).tolist() == [0, 1, 2] and not near_by.ghost_on[:, 1].any()
    assert near_by.ghost_x[:3, 0].tolist() == [10.0] * 3 and near_by.ghost_x[3:, 0].tolist() == [0.0] * 3
    further = Restriction("ghost", 0.3, 20.0, 40.0).project(errors, view)
    assert np.flatnonzero(further.ghost_on[:, 1]).tolist() == [2, 3] and not further.ghost_on[:, 0].any()


@pytest.mark.parametrize("kind, magnitude, near, far", [("flip", 1.0, 0.0, 20.0), ("drop", -1.0, 0.0, 20.0),
                                                        ("drop", float("nan"), 0.0, 20.0), ("drop", 1.0, 20.0, 20.0)])
def test_a_restriction_outside_its_space_is_refused(kind, magnitude, near, far):
    with pytest.raises(ValueError):
        Restriction(kind, magnitude, near, far)
