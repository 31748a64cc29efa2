"""The two-stage optimisation-based planner (docs/obp.md) on obp_overtake."""

import itertools
import math
from dataclasses import replace

import casadi as ca
import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from advperc_ros.backends.embedded import Stack
from advperc_ros.configs import core_configs
from advperc_ros.core.ego_motion import follow_plan
from advperc_ros.core.geometry import Polyline, Polylines
from advperc_ros.core.perception_errors import PerceptionErrors
from advperc_ros.core.planners.base import Planner, PlannerStats, PlanningContext, planner_stats
from advperc_ros.core.planners.obp import OBPPlanner
from advperc_ros.core.planners.obp.config import LANE_SNAP_ANGLE, STATIC_SPEED
from advperc_ros.core.planners.obp.dynamics import NUMERIC, SYMBOLIC, bicycle_rk4
from advperc_ros.core.planners.obp.prediction import ellipse_axes, track_velocities
from advperc_ros.core.planners.registry import load_planner
from advperc_ros.core.scenario_spec import build_scenario
from advperc_ros.core.typical import TypicalErrorConfig, sample_typical_errors
from advperc_ros.exceptions import PluginError
from advperc_ros.params import load_params

STATIONARY, ONCOMING = 0, 1  # agent slots in scenarios/obp_overtake.yaml
TYPICAL_SAMPLES = 5  # each rollout takes seconds; `advperc check-typical` runs the paper's 100 (docs/commands.md)


def _spec(repo, **changes):
    spec = yaml.safe_load((repo / "scenarios" / "obp_overtake.yaml").read_text())
    return build_scenario({**spec, **changes}, "obp_overtake")


@pytest.fixture(scope="module")
def scenario(repo):
    return _spec(repo)


@pytest.fixture(scope="module")
def params(repo):
    return load_params(repo / "config" / "obp_overtake.yaml")


@pytest.fixture(scope="module")
def stack(scenario, params):
    return Stack(scenario, core_configs(params))


@pytest.fixture(scope="module")
def ground_truth(stack, scenario):
    """The ground-truth rollout, with tracks and plans, and the planner's failure count after it."""
    result = stack.rollout(PerceptionErrors.none(*scenario.agents.shape), record=True)
    return result, stack.planner.failures


def _lateral(scenario, xy):
    return scenario.route.project(np.asarray(xy))[1]


# ---------------------------------------------------------------- (a) ground truth

def test_ground_truth_overtakes_after_the_oncoming_car_and_returns_to_its_lane(scenario, ground_truth):
    result, failures = ground_truth
    agents = scenario.agents
    assert result.inconclusive is None
    assert result.num_frames == scenario.num_frames
    assert not result.collided
    assert result.min_signed_distance > 0.3
    assert failures == 0
    lateral = _lateral(scenario, result.ego_xy)
    assert lateral.max() > 2.0  # it pulled out into the oncoming lane
    assert abs(lateral[-1]) < 0.5  # and came back to its lane
    # its rear bumper is past the stationary car's front
    assert result.ego[-1, 0] - 4.6 / 2 > agents.x[-1, STATIONARY] + agents.length[-1, STATIONARY] / 2
    # it waited: while it was out of its lane, the oncoming car had already passed it
    out = np.flatnonzero(lateral > 1.0)
    assert np.all(agents.x[out, ONCOMING] < result.ego[out, 0])
    # the plans start at the ego and cover the horizon at the frame period
    plan = result.plans[0]
    assert plan.t[0] == 0.0 and plan.x[0] == result.ego[0, 0]
    np.testing.assert_allclose(np.diff(plan.t), scenario.dt)
    assert plan.t[-1] == pytest.approx(6.0)


# ---------------------------------------------------------------- (b) typical errors

def test_typical_errors_cause_no_collision(stack, scenario):
    rng = np.random.default_rng(2024)
    failures = []
    for _ in range(TYPICAL_SAMPLES):
        result = stack.rollout(sample_typical_errors(scenario.agents.shape, rng, TypicalErrorConfig()))
        assert result.inconclusive is None
        assert not result.collided, f"min signed distance {result.min_signed_distance:.3f}"
        assert result.min_signed_distance > 0.0
        failures.append(stack.planner.failures)
    assert sum(failures) <= TYPICAL_SAMPLES  # solver failures stay rare (each one is a fallback)


# ---------------------------------------------------------------- (c) the heuristic's first step

def test_dropping_the_stationary_car_makes_it_collide(stack, scenario):
    num_frames, num_agents = scenario.agents.shape
    errors = PerceptionErrors.none(num_frames, num_agents).with_drop(STATIONARY, 0, num_frames - 1)
    result = stack.rollout(errors)
    assert result.collided
    assert int(np.argmin(result.distances[-1])) == STATIONARY


# ---------------------------------------------------------------- (d) why stage 1 exists

def test_single_stage_nlp_fails_where_the_two_stage_planner_succeeds(repo, params, ground_truth):
    """The NLP alone, warm-started on a straight line along the route, cannot pick the manoeuvre
    (stay behind / pass, before / after the oncoming car): IPOPT fails over and over on the approach
    and the ego drives on stale plans and emergency braking. The two-stage planner never fails."""
    _, two_stage_failures = ground_truth
    assert two_stage_failures == 0
    short = _spec(repo, duration=8.0)  # the approach to the stationary car
    single = replace(params, planner_params={**params.planner_params, "single_stage": True})
    stack = Stack(short, core_configs(single))
    result = stack.rollout(PerceptionErrors.none(*short.agents.shape))
    assert result.inconclusive is None
    assert result.collided or stack.planner.failures >= 20, stack.planner.failures
    assert stack.planner.last_class == "single-stage"


# ---------------------------------------------------------------- (e) solver failure fallback

def _context(scenario):
    return PlanningContext(route=scenario.route, lanes=scenario.lanes, dt=scenario.dt, ego_length=4.6, ego_width=1.9)


def _tracks(*rows):
    """Tracks from (x, y, yaw, vx) rows, 4.6 x 1.9 m."""
    arr = np.array(rows, dtype=float).reshape(-1, 4)
    n = len(arr)
    return {"ids": np.arange(1, n + 1), "x": arr[:, 0], "y": arr[:, 1], "yaw": arr[:, 2], "vx": arr[:, 3],
            "vy": np.zeros(n), "length": np.full(n, 4.6), "width": np.full(n, 1.9), "height": np.full(n, 1.6)}


def _speeds(plan):
    return np.array([follow_plan(plan, t).v for t in plan.t[1:-1]])


def _pacing_car(ego):
    """A car keeping pace 2.4 m to the ego's left: its box never touches the ego's, but the ego is
    inside its ellipse and cannot get out within a step, so the NLP is infeasible."""
    return _tracks((ego.x, ego.y + 2.4, 0.0, ego.v))


def test_failed_solve_without_previous_plan_brakes_along_the_route(scenario):
    planner = OBPPlanner(_context(scenario))
    ego = scenario.ego_start
    plan = planner.plan(0.0, ego, _pacing_car(ego))
    assert planner.failures == 1 and planner.fallbacks == {"shifted": 0, "braking": 1}
    assert plan.t[0] == 0.0 and (plan.x[0], plan.y[0]) == (ego.x, ego.y)
    np.testing.assert_allclose(_lateral(scenario, np.stack([plan.x, plan.y], axis=1)), 0.0, atol=1e-9)
    v = _speeds(plan)
    assert v[0] == pytest.approx(ego.v - 5.0 * scenario.dt, abs=0.3)  # max_decel from the start
    assert v[-1] == pytest.approx(0.0, abs=1e-9)  # to a standstill
    assert np.all(np.diff(v) <= 1e-9)


def test_iteration_limit_counts_as_a_failure(scenario):
    """IPOPT stopped by max_iterations with an infeasible iterate is a failed solve."""
    from advperc_ros.core.perception_errors import inject
    from advperc_ros.core.tracker import Tracker

    tracks = Tracker().step(0.0, inject(scenario.agents, PerceptionErrors.none(*scenario.agents.shape)).frame(0))
    planner = OBPPlanner(_context(scenario), max_iterations=1)
    plan = planner.plan(0.0, scenario.ego_start, tracks)
    assert planner.failures == 1 and planner.fallbacks["braking"] == 1
    assert follow_plan(plan, 0.1).v < scenario.ego_start.v


def test_failures_of_a_rollout_reach_the_search_log(scenario, params):
    """Each rollout's failed solves are in its search-log row, and the search goes on."""
    from advperc_ros.core.search.problem import AttackProblem

    starved = Stack(scenario, core_configs(replace(params, planner_params={**params.planner_params, "max_iterations": 1})))
    problem = AttackProblem(scenario, starved.rollout, "nds_t")
    evaluation = problem.evaluate(PerceptionErrors.none(*scenario.agents.shape), "ground_truth")
    row = problem.log[-1]
    stats = starved.planner.stats()
    assert row.planner_failures == evaluation.rollout.planner_failures == stats.failures > 0
    assert stats.failures == starved.planner.failures == sum(starved.planner.fallbacks.values())
    assert len(stats.solve_times) == evaluation.rollout.num_frames  # a call per frame: replan_period 0, no collision
    assert planner_stats(starved.planner) == stats
    # a plan call solves once, so each failure is a frame of its own the rollout records (planner_failure rule)
    assert len(evaluation.rollout.fallback_frames) == stats.failures


def test_failed_solve_uses_previous_plan_shifted_when_it_is_still_safe(scenario):
    planner = OBPPlanner(_context(scenario))
    ego = scenario.ego_start
    first = planner.plan(0.0, ego, _tracks())
    assert planner.failures == 0
    ego = follow_plan(first, 0.1)
    plan = planner.plan(0.1, ego, _pacing_car(ego))
    assert planner.failures == 1 and planner.fallbacks == {"shifted": 1, "braking": 0}
    assert plan.t[0] == pytest.approx(0.1)
    assert plan.t[-1] == pytest.approx(first.t[-1])
    np.testing.assert_allclose(plan.x, np.interp(plan.t, first.t, first.x), atol=1e-9)
    np.testing.assert_allclose(plan.y, np.interp(plan.t, first.t, first.y), atol=1e-9)


def test_failed_solve_brakes_along_previous_path_when_the_shifted_plan_would_collide(scenario):
    planner = OBPPlanner(_context(scenario))
    ego = scenario.ego_start
    first = planner.plan(0.0, ego, _tracks())
    ego = follow_plan(first, 0.1)
    blocked = _tracks((ego.x + 7.0, ego.y, 0.0, 0.0))  # a stopped car 7 m ahead at 10 m/s: no way out
    plan = planner.plan(0.1, ego, blocked)
    assert planner.failures == 1 and planner.fallbacks == {"shifted": 0, "braking": 1}
    assert plan.t[0] == pytest.approx(0.1) and plan.x[0] == ego.x
    v = _speeds(plan)
    assert v[0] < ego.v - 0.3
    assert v[-1] == pytest.approx(0.0, abs=1e-9)
    # along the previous path (straight along the lane here)
    np.testing.assert_allclose(plan.y, ego.y, atol=1e-3)
    assert planner.stats().failures == 1 and len(planner.stats().solve_times) == 2
    planner.reset()
    assert planner.failures == 0 and planner.fallbacks == {"shifted": 0, "braking": 0}
    assert planner.stats() == PlannerStats(failures=0, solve_times=())


# ---------------------------------------------------------------- (f) determinism

def test_deterministic(scenario, params, ground_truth):
    result, _ = ground_truth
    again = Stack(scenario, core_configs(params)).rollout(PerceptionErrors.none(*scenario.agents.shape), record=True)
    assert np.array_equal(again.ego, result.ego)
    assert np.array_equal(again.distances, result.distances)
    for a, b in zip(again.plans, result.plans):
        assert np.array_equal(a.t, b.t) and np.array_equal(a.x, b.x) and np.array_equal(a.y, b.y)
        assert np.array_equal(a.yaw, b.yaw)


# ---------------------------------------------------------------- loading and parameters

def test_loaded_by_name_with_params_file_values(scenario, params):
    planner = load_planner("obp", _context(scenario), {**params.planner_params, "max_obstacles": 3, "horizon": 5})
    assert isinstance(planner, OBPPlanner) and isinstance(planner, Planner)
    assert planner.config.horizon == 5.0 and isinstance(planner.config.horizon, float)
    assert planner.config.target_speed == 10.0


@pytest.mark.parametrize("params, name", [
    ({"no_such_param": 1.0}, "no_such_param"),
    ({"target_speed": "fast"}, "target_speed"),
    ({"horizon": 0.0}, "horizon"),
    ({"step": -0.3}, "step"),
    ({"safety_margin": -0.1}, "safety_margin"),
    ({"max_cpu_time": float("inf")}, "max_cpu_time"),
    ({"max_obstacles": 2.5}, "max_obstacles"),
    ({"max_iterations": 0}, "max_iterations"),
    ({"max_steer": 2.0}, "max_steer"),
    ({"single_stage": 1}, "single_stage"),
])
def test_load_refuses_bad_params_in_one_line_naming_planner_and_parameter(scenario, params, name):
    with pytest.raises(PluginError) as refused:
        load_planner("obp", _context(scenario), params)
    message = str(refused.value)
    assert "'obp'" in message and f"'{name}'" in message and "\n" not in message


def test_out_of_range_is_a_value_error_of_the_planner_itself(scenario):
    with pytest.raises(ValueError, match="'horizon'"):
        OBPPlanner(_context(scenario), horizon=0.0)


def test_replan_period_holds_the_plan(scenario):
    planner = OBPPlanner(_context(scenario), replan_period=0.5)
    ego = scenario.ego_start
    first = planner.plan(0.0, ego, _tracks())
    assert planner.plan(0.3, follow_plan(first, 0.3), _tracks()) is first
    assert planner.plan(0.5, follow_plan(first, 0.5), _tracks()) is not first


def test_the_nlp_and_the_plan_integrate_one_bicycle_model():
    """The NLP's dynamics (CasADi symbols) and the plan's poses between its nodes (floats) come from
    the same bicycle_rk4, so the plan is the NLP's own trajectory (bit for bit on the development
    machine; a tolerance far below any physical effect elsewhere)."""
    xs, us = ca.SX.sym("x", 4), ca.SX.sym("u", 2)
    symbolic = ca.Function("substeps", [xs, us], bicycle_rk4(xs, us[0], us[1], 0.1, 2.7, 3, SYMBOLIC))
    rng = np.random.default_rng(0)
    for _ in range(50):
        state, (accel, steer) = rng.normal(size=4) * [20.0, 20.0, 2.0, 8.0], rng.normal(size=2) * [2.0, 0.3]
        numeric = bicycle_rk4(state, float(accel), float(steer), 0.1, 2.7, 3, NUMERIC)
        for a, b in zip(symbolic(state, [accel, steer]), numeric, strict=True):
            np.testing.assert_allclose(np.asarray(a).ravel(), b, rtol=0.0, atol=1e-12)


def test_nlp_size_with_the_defaults(stack):
    """As docs/obp.md states it: 124 variables, 340 constraints, 287 parameters."""
    assert stack.planner.stage2.size == {"variables": 124, "constraints": 340, "parameters": 287}


def test_ellipses_contain_the_inflated_box():
    """Every point of the box grown by the ego's circle radius lies inside the ellipse."""
    radius = np.hypot(4.6 / 6, 1.9 / 2)
    a, b = ellipse_axes(2.3 + 0.2, 0.95 + 0.2, radius)
    phi = np.linspace(0, 2 * np.pi, 7201)
    corners = np.array([[1, 1], [-1, 1], [-1, -1], [1, -1]]) * [2.5, 1.15]
    pts = (corners[:, None, :] + radius * np.stack([np.cos(phi), np.sin(phi)], axis=1)[None]).reshape(-1, 2)
    assert np.all((pts[:, 0] / a[0]) ** 2 + (pts[:, 1] / b[0]) ** 2 <= 1.0 + 1e-9)
    assert b[0] < 3.5 - 0.5  # narrow enough for cars in adjacent lanes to pass each other


# ---------------------------------------------------------------- infeasible at once (docs/obp.md)

@pytest.fixture()
def verdicts(monkeypatch):
    """The certificate's verdict on every solve, while IPOPT solves each problem anyway."""
    from advperc_ros.core.planners.obp import stage2

    seen: list[bool] = []

    def recorded(*args):
        seen.append(stage2_certificate(*args))
        return False

    stage2_certificate = stage2.certainly_infeasible
    monkeypatch.setattr(stage2, "certainly_infeasible", recorded)
    return seen


@settings(max_examples=120, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(speed=st.floats(0.0, 12.0), cars=st.lists(st.tuples(st.floats(-6.0, 9.0), st.floats(-3.0, 3.0),
                                                            st.floats(-math.pi, math.pi), st.floats(0.0, 12.0)),
                                                  min_size=1, max_size=3),
       replanned=st.booleans())
def test_a_problem_certified_infeasible_is_one_ipopt_fails(scenario, verdicts, speed, cars, replanned):
    """Sound: wherever the certificate skips IPOPT, IPOPT, run instead, fails (so the fallback answers
    exactly as it would have). Cars are put on and around the ego at any heading and speed, with and
    without the previous plan's controls bounding the first rates."""
    planner = OBPPlanner(_context(scenario))
    ego = replace(scenario.ego_start, v=speed)
    t = 0.0
    if replanned:
        ego, t = follow_plan(planner.plan(0.0, ego, _tracks()), 0.1), 0.1
    verdicts.clear()
    c, s = math.cos(ego.yaw), math.sin(ego.yaw)
    rows = [(ego.x + dx * c - dy * s, ego.y + dx * s + dy * c, yaw, v) for dx, dy, yaw, v in cars]
    planner.plan(t, ego, _tracks(*rows))
    assert (verdicts == [True] and planner.failures == 1) or verdicts == [False]


def test_the_certificate_catches_a_car_on_the_ego_and_passes_a_clear_road(scenario):
    """Not vacuous: a car on the ego (the attack's usual end) is certified, and solving is skipped;
    a car well ahead is not."""
    planner = OBPPlanner(_context(scenario))
    solver, calls = planner.stage2._solver, []

    class Counted:
        def __call__(self, **problem):
            calls.append(1)
            return solver(**problem)

        def stats(self):
            return solver.stats()

    planner.stage2._solver = Counted()
    ego = scenario.ego_start
    planner.plan(0.0, ego, _tracks((ego.x + 0.5, ego.y + 0.3, 0.0, 0.0)))
    assert planner.failures == 1 and calls == []
    planner.plan(0.1, ego, _tracks((ego.x + 40.0, ego.y, 0.0, 0.0)))
    assert planner.failures == 1 and calls == [1]


def test_a_rollout_is_the_same_with_and_without_the_certificate(stack, scenario, ground_truth, monkeypatch):
    """Bit for bit: a rollout in which an error makes the NLP infeasible over and over (the oncoming car
    seen 3 m into the ego's lane, for 0.8 s from 1 s before it passes) drives, plans and fails exactly
    as with IPOPT on every problem."""
    from advperc_ros.core.planners.obp import stage2

    passing = int(np.argmin(ground_truth[0].distances[:, ONCOMING]))
    errors = PerceptionErrors.none(*scenario.agents.shape)
    shifted = errors.dy.copy()
    shifted[passing - 10:passing - 2, ONCOMING] = -3.0
    errors = errors.with_arrays(dy=shifted)
    skipped: list[bool] = []
    certificate = stage2.certainly_infeasible
    monkeypatch.setattr(stage2, "certainly_infeasible", lambda *a: skipped.append(certificate(*a)) or skipped[-1])
    certified = stack.rollout(errors, record=True)
    failures = stack.planner.failures
    monkeypatch.setattr(stage2, "certainly_infeasible", lambda *a: False)
    solved = stack.rollout(errors, record=True)
    assert failures == stack.planner.failures >= sum(skipped) > 0
    assert np.array_equal(certified.ego, solved.ego) and np.array_equal(certified.distances, solved.distances)
    assert certified.fallback_frames == solved.fallback_frames
    for a, b in zip(certified.plans, solved.plans, strict=True):
        assert all(np.array_equal(getattr(a, f), getattr(b, f)) for f in ("t", "x", "y", "yaw"))


def _snapped_one_lane_at_a_time(tracks, lanes, widths):
    """The velocities track_velocities gives, computed as its definition reads: each lane in turn, a track taking
    the lane's direction where it is inside the lane, moving within LANE_SNAP_ANGLE of it and nearer its centre
    line than to any lane taken before (so the first of two as near keeps it)."""
    vx, vy = np.array(tracks["vx"], float), np.array(tracks["vy"], float)
    speed = np.hypot(vx, vy)
    slow = speed < STATIC_SPEED
    vx[slow], vy[slow] = 0.0, 0.0
    xy = np.stack([tracks["x"], tracks["y"]], axis=1)
    nearest, out_x, out_y = np.full(len(vx), np.inf), vx.copy(), vy.copy()
    for line, width in zip(lanes, widths):
        s, lateral = line.project(xy)
        heading = line.heading(s)
        along = vx * np.cos(heading) + vy * np.sin(heading)
        take = ~slow & (along > math.cos(LANE_SNAP_ANGLE) * speed) & (np.abs(lateral) < width / 2.0)
        take &= np.abs(lateral) < nearest
        out_x, out_y = np.where(take, along * np.cos(heading), out_x), np.where(take, along * np.sin(heading), out_y)
        nearest = np.where(take, np.abs(lateral), nearest)
    return out_x, out_y


_COORDINATE = st.integers(-6, 6).map(float)
_CENTRE_LINE = st.lists(st.tuples(_COORDINATE, _COORDINATE), min_size=2, max_size=5).filter(
    lambda points: any(a != b for a, b in itertools.pairwise(points)))


@settings(max_examples=300, deadline=None)
@given(lanes=st.lists(st.tuples(_CENTRE_LINE, st.sampled_from([2.0, 3.5, 6.0])), min_size=1, max_size=6),
       tracks=st.lists(st.tuples(_COORDINATE, _COORDINATE, _COORDINATE.map(lambda v: 2.0 * v),
                                 _COORDINATE.map(lambda v: 2.0 * v)), min_size=1, max_size=8))
@example(lanes=[([(0.0, 0.0), (4.0, 0.0)], 2.0)], tracks=[(1.0, 1.0, 4.0, 0.0)])  # on the lane's edge: not inside
@example(lanes=[([(0.0, 0.0), (4.0, 1.0)], 6.0), ([(0.0, 2.0), (4.0, 1.0)], 6.0)],  # as near two lanes, both its way
         tracks=[(2.0, 1.0, 4.0, 0.0)])
def test_tracks_snap_to_the_lanes_as_one_lane_at_a_time_would(lanes, tracks):
    """ObP projects every track onto every lane at once (a recording has a hundred lanes): the velocities are
    those of the definition's lane-by-lane reading, to the bit, ties between lanes and tracks on vertices
    included (a grid of coordinates and velocities makes them common: a track moving along a lane, on its edge, or
    as near two lanes that both point its way)."""
    lines = [Polyline(np.array(points)) for points, _ in lanes]
    widths = np.array([width for _, width in lanes])
    table = np.array(tracks)
    given_tracks = {"x": table[:, 0], "y": table[:, 1], "vx": table[:, 2], "vy": table[:, 3]}
    setup = type("LanesOnly", (), {"lanes": Polylines(lines), "lane_half_widths": widths / 2.0})()
    got = track_velocities(given_tracks, setup)
    expected = _snapped_one_lane_at_a_time(given_tracks, lines, widths)
    assert got[0].tolist() == expected[0].tolist() and got[1].tolist() == expected[1].tolist()
