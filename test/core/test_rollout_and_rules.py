"""Open-loop rollout, collision rule and ego motion."""

import signal
import time
from dataclasses import replace

import numpy as np
import pytest
import shapely

from advperc_ros.core.boxes import BoxSequence
from advperc_ros.core.ego_motion import follow_plan
from advperc_ros.exceptions import PlanError
from advperc_ros.core.perception_errors import PerceptionErrors, inject
from advperc_ros.core.geometry import box_corners, signed_box_distance, wrap_angle
from advperc_ros.core.planners.base import PlanningContext, Trajectory
from advperc_ros.core.planners.idm import IDMPlanner
from advperc_ros.core.rollout import RolloutConfig, rollout
from advperc_ros.core.rules.contact import CollisionRule
from advperc_ros.core.scenario import EgoState
from advperc_ros.core.scenario_spec import build_scenario
from advperc_ros.core.tracker import Tracker
from toy_scenarios import FOLLOW_SPEC

EGO_LENGTH, EGO_WIDTH = 4.6, 1.9

SPEC = FOLLOW_SPEC
SCENARIO = build_scenario(SPEC)
T, N = SCENARIO.agents.shape
CONTEXT = PlanningContext(
    route=SCENARIO.route, lanes=SCENARIO.lanes, dt=SCENARIO.dt, ego_length=EGO_LENGTH, ego_width=EGO_WIDTH
)


def idm():
    return IDMPlanner(CONTEXT, target_speed=14.0)


def run(errors, planner=None, tracker=None, **config):
    return rollout(SCENARIO, errors, tracker or Tracker(), planner or idm(), RolloutConfig(**config))


NONE = PerceptionErrors.none(T, N)
DROP_LEAD = NONE.with_drop(0, 0, T - 1)


def agent_box(k, j):
    a = SCENARIO.agents
    return box_corners(a.x[k, j], a.y[k, j], a.yaw[k, j], a.length[k, j], a.width[k, j])


def ego_box(row):
    return box_corners(row[0], row[1], row[2], EGO_LENGTH, EGO_WIDTH)


# ---------------------------------------------------------------- scenario sanity

def test_scenario_built_as_specified():
    assert (T, N) == (101, 2)
    assert SCENARIO.dt == pytest.approx(0.1)
    a = SCENARIO.agents
    np.testing.assert_allclose(a.x[:, 0], -100.0 + 120.0 + 8.0 * SCENARIO.times)
    np.testing.assert_allclose(a.y[:, 0], -1.75)
    np.testing.assert_allclose(a.x[:, 1], 500.0 - 250.0 - 10.0 * SCENARIO.times)
    np.testing.assert_allclose(a.yaw[:, 1], np.pi)
    assert SCENARIO.ego_start == EgoState(0.0, -1.75, 0.0, 8.0)


# ---------------------------------------------------------------- verdicts

def test_ground_truth_rollout_does_not_collide():
    result = run(NONE)
    assert result.inconclusive is None
    assert not result.collided
    assert result.num_frames == T
    assert result.min_signed_distance > 1.0
    # the ego keeps behind the lead: its speed settles near the lead's
    assert result.ego[-1, 3] == pytest.approx(8.0, abs=0.5)


def test_full_drop_of_lead_collides_and_rule_is_signed_box_distance():
    result = run(DROP_LEAD)
    assert result.collided
    assert result.inconclusive is None
    k = result.num_frames - 1
    assert k < T - 1  # stopped at the collision
    rule = result.rule
    assert rule[k] < 0.0
    assert np.all(rule[:k] >= 0.0)  # the first violation
    assert result.min_signed_distance == rule[k]
    # at the collision frame, the rule is the signed box distance of ego and lead boxes
    assert rule[k] == pytest.approx(float(signed_box_distance(ego_box(result.ego[k]), agent_box(k, 0))), abs=1e-12)
    assert shapely.Polygon(ego_box(result.ego[k])).intersects(shapely.Polygon(agent_box(k, 0)))
    # a rear-end: at 10 Hz and a few m/s closing speed the penetration is shallow
    assert -1.0 < rule[k]
    # before, the rule is the gap as shapely measures it, for both agents
    for kk in (0, k // 2, k - 1):
        for j in range(N):
            gap = shapely.Polygon(ego_box(result.ego[kk])).distance(shapely.Polygon(agent_box(kk, j)))
            assert result.distances[kk, j] == pytest.approx(gap, abs=1e-9)


def test_lateral_offset_hides_the_lead_like_a_drop():
    """Detections shifted 3.5 m into the next lane leave the corridor: the IDM ego runs into the lead."""
    errors = NONE.copy()
    errors.dy[:, 0] = 3.5
    result = run(errors)
    assert result.collided


def test_short_early_drop_does_not_collide():
    result = run(NONE.with_drop(0, 0, 9))
    assert not result.collided
    assert result.num_frames == T


def test_every_frame_is_frame_k_for_every_k():
    valid = SCENARIO.agents.valid & (np.random.default_rng(2).random((T, N)) > 0.3)  # some boxes, all of them
    valid[:3] = False  # and none
    boxes = replace(SCENARIO.agents, valid=valid)
    every = boxes.every_frame()
    assert len(every) == T
    for k in range(T):
        one = boxes.frame(k)
        assert every[k].keys() == one.keys()
        for name, values in one.items():
            assert values.dtype == every[k][name].dtype
            np.testing.assert_array_equal(every[k][name], values)


def test_stop_at_collision_truncates_otherwise_runs_all_frames():
    short = run(DROP_LEAD, stop_at_collision=True)
    full = run(DROP_LEAD, stop_at_collision=False)
    k = short.num_frames - 1
    assert full.num_frames == T
    assert full.collided
    np.testing.assert_array_equal(full.ego[: k + 1], short.ego)
    np.testing.assert_array_equal(full.distances[: k + 1], short.distances)
    assert full.min_signed_distance <= short.min_signed_distance


def test_collision_distances_inf_for_absent_agents():
    spec = dict(SPEC, agents=[dict(SPEC["agents"][0], appear=2.0, disappear=5.0), SPEC["agents"][1]])
    scenario = build_scenario(spec)
    ego = scenario.ego_start
    d = CollisionRule(scenario.agents, EGO_LENGTH, EGO_WIDTH).distances(np.array([[ego.x, ego.y, ego.yaw]] * 3), [0, 30, 60])
    assert d[0, 0] == np.inf and np.isfinite(d[0, 1])
    assert np.isfinite(d[1, 0])
    assert d[2, 0] == np.inf
    result = rollout(scenario, PerceptionErrors.none(*scenario.agents.shape), Tracker(),
                     IDMPlanner(CONTEXT, target_speed=14.0))
    assert np.all(np.isinf(result.distances[:20, 0]))
    assert np.all(np.isfinite(result.distances[20:51, 0]))
    assert np.all(np.isinf(result.distances[51:, 0]))


def test_collision_distances_equal_shapely_on_random_agents():
    """One frame of 400 random agent boxes round a random ego, overlapping and apart, a quarter absent."""
    rng = np.random.default_rng(5)
    n = 400
    agents = BoxSequence.empty(1, n)
    agents.valid[0] = rng.random(n) > 0.25
    agents.x[0], agents.y[0] = rng.uniform(-9.0, 9.0, n), rng.uniform(-6.0, 6.0, n)
    agents.yaw[0] = rng.uniform(-np.pi, np.pi, n)
    agents.length[0], agents.width[0] = rng.uniform(3.0, 6.0, n), rng.uniform(1.5, 2.5, n)
    ego = EgoState(0.3, -0.2, 0.7, 5.0)
    got = CollisionRule(agents, EGO_LENGTH, EGO_WIDTH).distances(np.array([[ego.x, ego.y, ego.yaw]]), [0])[0]
    assert np.all(got[~agents.valid[0]] == np.inf)
    valid = agents.valid[0]
    ego_poly = shapely.Polygon(ego_box((ego.x, ego.y, ego.yaw)))
    polys = shapely.polygons(box_corners(agents.x[0], agents.y[0], agents.yaw[0], agents.length[0], agents.width[0]))
    gap, hit = shapely.distance(ego_poly, polys), shapely.intersects(ego_poly, polys)
    apart = valid & ~hit
    np.testing.assert_allclose(got[apart], gap[apart], rtol=0.0, atol=1e-9)
    assert np.all(got[valid & hit] <= 0.0)
    # overlapping: the penetration depth of signed_box_distance, tested against shapely in test_geometry
    corners = box_corners(agents.x[0, valid], agents.y[0, valid], agents.yaw[0, valid], agents.length[0, valid], agents.width[0, valid])
    np.testing.assert_allclose(got[valid], signed_box_distance(ego_box((ego.x, ego.y, ego.yaw))[None], corners), atol=1e-12)
    assert (valid & hit).sum() > 50 and apart.sum() > 50


def test_collision_rule_many_frames_at_once_equal_one_at_a_time_and_may_touch_misses_no_contact():
    """A rollout measures most frames in one pass and, during the drive, only those where the ego
    may touch an agent: the values must be those of one frame at a time, bit for bit, and a frame
    may_touch passes over must have no contact."""
    rng = np.random.default_rng(11)
    passed_over = []
    for frames, slots in ((1, 1), (7, 3), (60, 5), (40, 83)):
        agents = BoxSequence.empty(frames, slots)
        agents.valid[:] = rng.random((frames, slots)) > 0.2
        agents.x[:], agents.y[:] = rng.uniform(-15.0, 15.0, (2, frames, slots))
        agents.x[~agents.valid] = np.nan  # padding may be nan
        agents.yaw[:] = rng.uniform(-np.pi, np.pi, (frames, slots))
        agents.length[:], agents.width[:] = rng.uniform(0.5, 12.0, (2, frames, slots))
        ego = np.column_stack([rng.uniform(-5.0, 5.0, (frames, 2)), rng.uniform(-4.0, 4.0, frames), np.full(frames, 3.0)])
        rule = CollisionRule(agents, EGO_LENGTH, EGO_WIDTH)
        together = rule.distances(ego, np.arange(frames))
        one_at_a_time = np.concatenate([rule.distances(ego[k : k + 1], [k]) for k in range(frames)])
        np.testing.assert_array_equal(together.view(np.int64), one_at_a_time.view(np.int64))
        passed = np.array([not rule.may_touch(EgoState(*row), k) for k, row in enumerate(ego)])
        assert np.all(together[passed] > 0.0)
        passed_over.append(passed)
    assert 0 < np.concatenate(passed_over).mean() < 1


def test_ego_footprint_from_config():
    """A longer ego touches the lead earlier."""
    normal = run(DROP_LEAD)
    long_ego = run(DROP_LEAD, ego_length=8.0)
    assert long_ego.collided
    assert long_ego.num_frames < normal.num_frames


# ---------------------------------------------------------------- inconclusive rollouts

class RaisingPlanner:
    """Drives like the IDM planner, raises at a given time."""

    def __init__(self, fail_at):
        self.inner = idm()
        self.fail_at = fail_at

    def reset(self):
        self.inner.reset()

    def plan(self, t, ego, tracks):
        if t >= self.fail_at - 1e-9:
            raise RuntimeError("solver exploded")
        return self.inner.plan(t, ego, tracks)


class ShortPlanner:
    """Returns a plan that ends before the next frame."""

    def reset(self):
        pass

    def plan(self, t, ego, tracks):
        return Trajectory(t=np.array([t, t + 0.05]), x=np.array([ego.x, ego.x + 0.4]),
                          y=np.array([ego.y, ego.y]), yaw=np.zeros(2))


def test_planner_that_raises_makes_rollout_inconclusive():
    result = run(NONE, planner=RaisingPlanner(fail_at=0.5))
    assert result.inconclusive is not None
    assert "RuntimeError" in result.inconclusive and "solver exploded" in result.inconclusive
    assert "frame 5" in result.inconclusive
    assert not result.collided
    assert result.num_frames == 6


def test_planner_raising_after_a_collision_gives_no_verdict():
    full = run(DROP_LEAD, stop_at_collision=False)
    k = int(np.argmax(full.rule < 0))
    result = run(DROP_LEAD, planner=RaisingPlanner(fail_at=(k + 5) * 0.1), stop_at_collision=False)
    assert result.min_signed_distance < 0.0
    assert result.inconclusive is not None
    assert not result.collided


class HangingPlanner(RaisingPlanner):
    """Drives like the IDM planner, then hangs (a minute's sleep, or a busy loop) at a given time."""

    def __init__(self, fail_at, busy):
        super().__init__(fail_at)
        self.busy = busy

    def plan(self, t, ego, tracks):
        if t >= self.fail_at - 1e-9:
            end = time.monotonic() + 60.0
            while time.monotonic() < end:
                if not self.busy:
                    time.sleep(60.0)
        return self.inner.plan(t, ego, tracks)


@pytest.mark.parametrize("busy", [False, True], ids=["sleeping", "busy"])
def test_a_hung_planner_makes_its_rollout_inconclusive_and_the_next_one_runs(busy):
    before = signal.getsignal(signal.SIGALRM)
    result = run(NONE, planner=HangingPlanner(fail_at=0.5, busy=busy), plan_timeout=0.2)
    assert result.inconclusive == "frame 5: planner raised PlanTimeout: no plan within 0.2 s"
    assert not result.collided and result.num_frames == 6
    assert signal.getsignal(signal.SIGALRM) is before and signal.getitimer(signal.ITIMER_REAL) == (0.0, 0.0)
    assert run(NONE, plan_timeout=5.0).inconclusive is None  # a planner within its time is not disturbed


def test_plan_not_covering_next_frame_is_inconclusive():
    result = run(DROP_LEAD, planner=ShortPlanner())
    assert result.inconclusive is not None
    assert "next frame" in result.inconclusive
    assert not result.collided
    assert result.num_frames == 1


def test_record_keeps_tracks_and_plans_per_frame():
    result = rollout(SCENARIO, NONE.with_drop(0, 30, 40), Tracker(), idm(), record=True)
    assert len(result.tracks) == len(result.plans) == result.num_frames == T
    assert all(isinstance(p, Trajectory) for p in result.plans)
    # track ids are the tracker's: the lead (slot 0) got 1, the oncoming car 2
    assert sorted(result.tracks[29]["ids"]) == [1, 2]
    # the lead is dropped on frames 30..40: its track coasts 9 frames and goes at the 10th (t - last_seen = 1 s)
    assert sorted(result.tracks[38]["ids"]) == [1, 2]
    assert list(result.tracks[39]["ids"]) == [2]
    assert list(result.tracks[40]["ids"]) == [2]
    assert sorted(result.tracks[41]["ids"]) == [2, 3]  # back, as a new track
    assert all(p.t[0] == pytest.approx(k * 0.1) for k, p in enumerate(result.plans))
    assert run(NONE).tracks is None


# ---------------------------------------------------------------- determinism

def test_rollout_is_deterministic_and_independent_of_previous_rollouts():
    rng = np.random.default_rng(0)
    errors = NONE.copy()
    errors.dx[:] = rng.normal(0.0, 0.3, errors.dx.shape)
    errors.dy[:] = rng.normal(0.0, 0.3, errors.dy.shape)
    errors.dyaw[:] = rng.normal(0.0, 0.05, errors.dyaw.shape)
    errors.fn[:] = rng.random(errors.fn.shape) < 0.2
    tracker, planner = Tracker(), idm()
    first = rollout(SCENARIO, errors, tracker, planner)
    rollout(SCENARIO, DROP_LEAD, tracker, planner)  # a different rollout in between, same objects
    second = rollout(SCENARIO, errors, tracker, planner)
    fresh = run(errors)
    for other in (second, fresh):
        assert np.array_equal(first.ego, other.ego)
        assert np.array_equal(first.distances, other.distances)
        assert first.inconclusive == other.inconclusive


def test_errors_must_match_scenario_shape():
    with pytest.raises(ValueError, match="shape"):
        run(PerceptionErrors.none(T - 1, N))


def test_inject_applies_offsets_and_drops():
    errors = NONE.copy()
    errors.dx[3, 0], errors.dy[3, 0], errors.dyaw[3, 1] = 1.5, -0.5, 0.2
    errors.fn[4, 1] = True
    seen = inject(SCENARIO.agents, errors)
    truth = SCENARIO.agents
    assert seen.x[3, 0] == truth.x[3, 0] + 1.5 and seen.y[3, 0] == truth.y[3, 0] - 0.5
    assert seen.yaw[3, 1] == pytest.approx(-np.pi + 0.2)  # wrapped
    assert not seen.valid[4, 1] and seen.valid[4, 0]
    np.testing.assert_array_equal(seen.vx, truth.vx)  # velocity and size stay true
    np.testing.assert_array_equal(seen.length, truth.length)


# ---------------------------------------------------------------- ego motion

def constant_speed_plan(t0=0.0, speed=5.0, yaw=0.0, steps=80, dt=0.1):
    t = t0 + dt * np.arange(steps + 1)
    d = speed * (t - t0)
    return Trajectory(t=t, x=10.0 + d * np.cos(yaw), y=-3.0 + d * np.sin(yaw), yaw=np.full(t.size, yaw))


@pytest.mark.parametrize("t_next", [0.1, 0.25, 4.0, 7.95, 8.0])
def test_follow_plan_derives_speed_from_poses(t_next):
    state = follow_plan(constant_speed_plan(yaw=0.7), t_next)
    assert state.v == pytest.approx(5.0, rel=1e-9)
    assert state.x == pytest.approx(10.0 + 5.0 * t_next * np.cos(0.7))
    assert state.y == pytest.approx(-3.0 + 5.0 * t_next * np.sin(0.7))
    assert state.yaw == pytest.approx(0.7)


def test_follow_plan_speed_of_accelerating_plan():
    t = 0.1 * np.arange(81)
    plan = Trajectory(t=t, x=0.5 * 2.0 * t**2, y=np.zeros_like(t), yaw=np.zeros_like(t))
    # central difference over [0.95, 1.05] of x = t^2 is exactly 2 t
    assert follow_plan(plan, 1.0).v == pytest.approx(2.0, abs=0.011)


@pytest.mark.parametrize("t_next, speed", [(0.9, 5.0), (1.0, 7.5), (1.1, 10.0), (1.5, 10.0)])
def test_follow_plan_speed_around_a_speed_step(t_next, speed):
    """5 m/s until t = 1 s, then 10 m/s: the speed is the displacement over half a pose spacing either side."""
    t = 0.1 * np.arange(31)
    x = np.where(t <= 1.0, 5.0 * t, 5.0 + 10.0 * (t - 1.0))
    plan = Trajectory(t=t, x=x, y=np.zeros_like(t), yaw=np.zeros_like(t))
    assert follow_plan(plan, t_next).v == pytest.approx(speed, rel=1e-9)


def test_follow_plan_interpolates_yaw_across_the_wrap():
    t = np.array([0.0, 0.2])
    plan = Trajectory(t=t, x=np.array([0.0, -1.0]), y=np.zeros(2), yaw=np.array([np.pi - 0.1, -np.pi + 0.1]))
    state = follow_plan(plan, 0.1)
    assert abs(abs(state.yaw) - np.pi) < 1e-9  # halfway is pi, not 0


def _follow_plan_with_numpy(plan, t_next):
    """follow_plan as it was written with np.unwrap and np.interp: the reference for its floats."""
    t = np.asarray(plan.t, dtype=float)
    values = np.stack([plan.x, plan.y, np.unwrap(plan.yaw)])
    x, y, yaw = (float(np.interp(t_next, t, row)) for row in values)
    half = 0.5 * float(np.min(np.diff(t)))
    before, after = max(t[0], t_next - half), min(t[-1], t_next + half)
    moved = np.hypot(np.interp(after, t, values[0]) - np.interp(before, t, values[0]),
                     np.interp(after, t, values[1]) - np.interp(before, t, values[1]))
    return EgoState(x=x, y=y, yaw=float(wrap_angle(yaw)), v=float(moved / (after - before)))


def test_follow_plan_equals_numpy_interp_and_unwrap_bit_for_bit():
    rng = np.random.default_rng(0)
    for case in range(3000):
        size = int(rng.integers(2, 40))
        t = np.cumsum(rng.uniform(0.01, 0.3, size)) + rng.uniform(-5, 5)
        if case % 4 == 0:  # a heading turning through the wrap at +-pi, also by steps of about pi
            yaw = wrap_angle(np.cumsum(rng.uniform(-3.5, 3.5, size)))
        else:
            yaw = rng.uniform(-0.5, 0.5) + np.cumsum(rng.normal(0.0, 0.05, size))
        yaw[rng.random(size) < 0.1] = -0.0
        x, y = np.cumsum(rng.uniform(0.0, 2.0, (2, size)), axis=1) * rng.uniform(-1e3, 1e3, (2, 1))
        if case % 5 == 0:  # standing still on some poses
            x[1:] = np.where(rng.random(size - 1) < 0.5, x[:-1], x[1:])
        plan = Trajectory(t=t, x=x, y=y, yaw=yaw)
        nexts = np.concatenate([t[[0, -1]], t[rng.integers(0, size, 2)], rng.uniform(t[0], t[-1], 4)])
        for t_next in (*nexts.tolist(), float(t[0]) - 5e-10, float(t[-1]) + 5e-10):
            assert follow_plan(plan, t_next) == _follow_plan_with_numpy(plan, t_next), (case, t_next)


def test_follow_plan_rejects_bad_plans():
    plan = constant_speed_plan(t0=1.0)
    with pytest.raises(PlanError, match="next frame"):
        follow_plan(plan, 9.5)
    with pytest.raises(PlanError, match="next frame"):
        follow_plan(plan, 0.9)
    for t in ([0.0, 0.1, 0.1], [0.0, 0.2, 0.1], [-np.inf, 0.0, 0.1], [0.0, np.nan, 0.1], [0.0, 0.1, np.inf],
              [np.nan, 0.0, 0.1], [0.0, 0.1, np.nan], [0.0], []):
        bad_t = Trajectory(t=np.array(t), x=np.zeros(len(t)), y=np.zeros(len(t)), yaw=np.zeros(len(t)))
        with pytest.raises(PlanError, match="finite and strictly increasing"):
            follow_plan(bad_t, 0.05)
    nan_pose = Trajectory(t=np.array([0.0, 0.1]), x=np.array([0.0, np.nan]), y=np.zeros(2), yaw=np.zeros(2))
    with pytest.raises(PlanError):
        follow_plan(nan_pose, 0.05)
    short_poses = Trajectory(t=np.array([0.0, 0.1, 0.2]), x=np.zeros(2), y=np.zeros(2), yaw=np.zeros(2))
    with pytest.raises(PlanError, match="3 timestamps but 2 poses"):
        follow_plan(short_poses, 0.05)
