"""The rulebook (core/rules/): each rule on hand-computed drives, nuPlan's defaults, the registry, and
the bundled ground truths violating none."""

from dataclasses import fields, is_dataclass

import numpy as np
import pytest
from toy_scenarios import FOLLOW_SPEC

from advperc_ros.backends.embedded import Stack
from advperc_ros.configs import core_configs
from advperc_ros.core.boxes import BoxSequence
from advperc_ros.core.geometry import Polyline
from advperc_ros.core.parameters import parameter_info
from advperc_ros.core.perception_errors import PerceptionErrors
from advperc_ros.core.planners.base import PlannerStats, Trajectory
from advperc_ros.core.rollout import RolloutConfig, rollout
from advperc_ros.core.rules.base import evaluate
from advperc_ros.core.rules.contact import CollisionRule
from advperc_ros.core.rules.inputs import RuleInputs, rule_inputs
from advperc_ros.core.rules.registry import RULES, rule_class
from advperc_ros.core.scenario import Lane
from advperc_ros.core.scenario_spec import build_scenario
from advperc_ros.core.tracker import Tracker
from advperc_ros.params import load_params

DT = 0.1
LENGTH, WIDTH = 4.6, 1.9
EAST = Lane(id="east", centerline=Polyline(np.array([[-1000.0, 0.0], [1000.0, 0.0]])), width=3.5)


def drive(x, y=0.0, yaw=0.0, v=None, agents=None, lanes=(EAST,), plan_valid=None, fallback_frames=None):
    """RuleInputs of an ego at states (x, y, yaw, v) per frame (scalars broadcast), among `agents`
    (a list of per-frame dicts, or none), on `lanes`; the distances measured by the collision rule."""
    x = np.asarray(x, dtype=float)
    ego = np.stack(np.broadcast_arrays(x, y, yaw, np.gradient(x, DT) if v is None else v), axis=1).astype(float)
    frames = ego.shape[0]
    boxes = BoxSequence.stack(agents) if agents else BoxSequence.empty(frames, 0)
    distances = CollisionRule(boxes, LENGTH, WIDTH).distances(ego, np.arange(frames))
    return RuleInputs(ego=ego, dt=DT, agents=boxes, distances=distances, lanes=tuple(lanes), route=EAST.centerline,
                      ego_length=LENGTH, ego_width=WIDTH,
                      plan_valid=np.ones(frames, bool) if plan_valid is None else plan_valid,
                      fallback_frames=fallback_frames)


def car(x, y=0.0, yaw=0.0, speed=0.0):
    """One agent's box in a frame, driving at `speed` along `yaw`."""
    return {"ids": np.array([1]), "x": np.array([x]), "y": np.array([y]), "yaw": np.array([yaw]),
            "vx": np.array([speed * np.cos(yaw)]), "vy": np.array([speed * np.sin(yaw)]),
            "length": np.array([LENGTH]), "width": np.array([WIDTH]), "height": np.array([1.6])}


def braking(v0, deceleration, frames):
    """Positions and speeds of an ego braking at a constant rate from v0 along +x."""
    t = DT * np.arange(frames)
    return v0 * t - 0.5 * deceleration * t**2, v0 - deceleration * t


def value(name, inputs, reference=None, **parameters):
    rule = rule_class(name)
    return evaluate(rule(rule.Parameters(**parameters) if parameters else None), inputs, reference)


# ---------------------------------------------------------------- the registry

def test_the_registry_lists_every_rule_with_its_meaning_unit_parameters_and_sources():
    assert set(RULES) >= {"collision", "at_fault_collision", "time_to_collision", "hard_braking", "comfort",
                          "phantom_braking", "drivable_area", "progress", "planner_failure"}
    for name in RULES:
        rule = rule_class(name)
        assert rule.name == name
        assert rule.meaning and "\n" not in rule.meaning and rule.unit
        assert is_dataclass(rule.Parameters) and rule.Parameters.__dataclass_params__.frozen
        defaults = rule.Parameters()
        for info in parameter_info(rule.Parameters):
            assert info.source and np.isfinite(info.default), (name, info)
        assert rule().parameters == defaults


def test_every_threshold_of_a_rule_the_search_judges_is_a_parameter_of_the_params_with_its_default_and_bounds():
    """One definition: the params schema's `rule.<rule>.<parameter>` is generated from the rule's own
    parameters; the contact rules, which every backend judges as the rollout runs, have none there."""
    from advperc_ros.params import SCHEMA, rule_parameter

    for name in RULES:
        for info in parameter_info(rule_class(name).Parameters):
            assert info.default is not None and (info.bounds.low, info.bounds.high) != (None, None), (name, info)
            dotted = rule_parameter(name, info.name)
            if name in ("collision", "at_fault_collision"):
                assert dotted not in SCHEMA
                continue
            param = SCHEMA[dotted]
            assert (param.type, param.default, param.low, param.high, param.positive) == \
                (float, info.default, info.bounds.low, info.bounds.high, info.bounds.positive)
            assert info.source in param.description
            if info.bounds.high is not None:  # every default lies within its own bounds
                assert info.default <= info.bounds.high


def test_a_rulebook_builds_each_rule_with_the_params_thresholds_and_the_defaults_elsewhere(repo):
    from advperc_ros.configs import rulebook

    params = load_params(repo / "config" / "idm_lane_following.yaml")
    defaults = rulebook(params.flat())
    assert all(defaults.rule(name).parameters == rule_class(name)().parameters for name in RULES)
    changed = rulebook(params.with_values(**{"rule.time_to_collision.least_min_ttc": 1.5}).flat())
    assert changed.rule("time_to_collision").parameters.least_min_ttc == 1.5
    assert changed.rule("time_to_collision").parameters.time_horizon == 3.0
    assert changed.rule("phantom_braking").parameters == rule_class("phantom_braking")().parameters
    # the time-to-collision bound moves the value by as much (r = ttc - bound): 1.3 s to contact head on
    head_on = drive(np.zeros(1), v=10.0, agents=[car(30.0, yaw=np.pi, speed=10.0)])
    before, after = (evaluate(book.rule("time_to_collision"), head_on).value for book in (defaults, changed))
    assert (before, after) == (pytest.approx(1.3 - 0.95), pytest.approx(1.3 - 1.5))


def test_an_unknown_rule_is_refused_naming_the_known_ones():
    with pytest.raises(ValueError, match=r"unknown rule 'speeding'.*collision"):
        rule_class("speeding")


def test_a_rule_that_compares_with_the_ground_truth_refuses_to_run_without_it():
    with pytest.raises(ValueError, match=r"progress.*reference"):
        value("progress", drive(np.zeros(5)))


def test_the_defaults_are_nuplans():
    """The figures of nuPlan's simulation_metric configs (script/config/common/simulation_metric/)."""
    assert [f.default for f in fields(rule_class("time_to_collision").Parameters)][:3] == [0.95, 0.1, 3.0]
    comfort = rule_class("comfort").Parameters()
    assert (comfort.min_lon_acceleration, comfort.max_lon_acceleration, comfort.max_abs_lat_acceleration,
            comfort.max_abs_yaw_rate, comfort.max_abs_yaw_acceleration, comfort.max_abs_lon_jerk,
            comfort.max_abs_jerk_magnitude) == (-4.05, 2.40, 4.89, 0.95, 1.93, 4.13, 8.37)
    assert rule_class("hard_braking").Parameters().min_lon_acceleration == -4.05
    assert rule_class("drivable_area").Parameters().max_violation == 0.3
    progress = rule_class("progress").Parameters()
    assert (progress.min_progress_ratio, progress.score_progress_threshold) == (0.2, 2.0)


# ---------------------------------------------------------------- motion rules

def test_hard_braking_of_a_constant_deceleration_is_its_excess_over_the_bound():
    x, v = braking(20.0, 5.0, 31)
    result = value("hard_braking", drive(x, v=v))
    np.testing.assert_allclose(result.per_frame, -5.0 + 4.05, atol=1e-9)
    assert result.first_violation == 0
    x, v = braking(20.0, 3.0, 31)
    assert value("hard_braking", drive(x, v=v)).value == pytest.approx(4.05 - 3.0, abs=1e-9)


def test_comfort_is_the_smallest_margin_as_a_fraction_of_its_bound():
    steady = value("comfort", drive(10.0 * DT * np.arange(40), v=10.0))
    np.testing.assert_allclose(steady.per_frame, 1.0, atol=1e-9)
    x, v = braking(20.0, 3.0, 31)
    assert value("comfort", drive(x, v=v)).value == pytest.approx(1.0 - 3.0 / 4.05, abs=1e-9)
    # a 1 rad/s turn at 1 m/s: the yaw rate beyond nuPlan's 0.95 rad/s, the rest within bounds
    t = DT * np.arange(40)
    turning = value("comfort", drive(np.sin(t), y=1.0 - np.cos(t), yaw=t, v=1.0))
    assert turning.value == pytest.approx(1.0 - 1.0 / 0.95, abs=1e-6)
    assert turning.first_violation == 0


def test_phantom_braking_is_braking_the_ground_truth_and_the_agents_ahead_do_not_need():
    x, v = braking(20.0, 5.0, 31)
    cruising = drive(20.0 * DT * np.arange(31), v=20.0)
    assert value("phantom_braking", drive(x, v=v), cruising).value == pytest.approx(-5.0 + 2.94, abs=1e-9)
    # the ground truth brakes as hard: no phantom
    assert value("phantom_braking", drive(x, v=v), drive(x, v=v)).value == pytest.approx(0.0, abs=1e-9)
    # a standing car 41 m ahead of an ego at 20 m/s: stopping 1 m short of it takes 5 m/s^2, and its DRAC
    # 25 (4 - t)^2 / (5 (t - 4)^2 + 2) stays within [4.88, 5) m/s^2 >= 2.94 all the way: it explains the braking
    standing = [car(41.0 + LENGTH) for _ in x]
    assert value("phantom_braking", drive(x, v=v, agents=standing), cruising).value == np.inf
    # the same car beside the ego's path does not
    beside = [car(41.0 + LENGTH, y=3.5) for _ in x]
    assert value("phantom_braking", drive(x, v=v, agents=beside), cruising).violated
    # nor does a lead 8 m ahead at the ego's own speed: closing at 0 m/s, it needs no braking at all
    lead = [car(float(xk) + 8.0 + LENGTH, speed=float(vk)) for xk, vk in zip(x, v)]
    assert value("phantom_braking", drive(x, v=v, agents=lead), cruising).value == pytest.approx(-5.0 + 2.94, abs=1e-9)


# ---------------------------------------------------------------- time to collision

@pytest.mark.parametrize("centres_apart, ttc", [
    (30.0, 1.3),  # a gap of 25.4 m closing at 20 m/s: boxes meet at 1.27 s, the 0.1 s step after is 1.3 s
    (20.0, 0.8),  # 15.4 m: 0.77 s, under nuPlan's 0.95 s bound
    (63.6, np.inf),  # 59 m: 2.95 s, beyond the last step nuPlan projects (2.9 s: its horizon is exclusive)
])
def test_time_to_collision_of_a_head_on_pair_is_nuplans_projection(centres_apart, ttc):
    inputs = drive(np.zeros(1), v=10.0, agents=[car(centres_apart, yaw=np.pi, speed=10.0)])
    assert value("time_to_collision", inputs).value == pytest.approx(ttc - 0.95)


def test_time_to_collision_ignores_agents_behind_a_stopped_ego_and_a_pair_that_passes():
    rear = drive(np.zeros(1), v=5.0, agents=[car(-10.0, speed=15.0)])
    assert value("time_to_collision", rear).value == np.inf
    stopped = drive(np.zeros(1), v=0.0, agents=[car(20.0, yaw=np.pi, speed=10.0)])
    assert value("time_to_collision", stopped).value == np.inf
    oncoming = drive(np.zeros(1), v=10.0, agents=[car(20.0, y=3.5, yaw=np.pi, speed=10.0)])
    assert value("time_to_collision", oncoming).value == np.inf


# ---------------------------------------------------------------- the road

def test_drivable_area_is_nuplans_tolerance_minus_the_farthest_corner_off_the_lanes():
    half_lane, half_car = 1.75, WIDTH / 2
    centred = value("drivable_area", drive(np.zeros(3), v=0.0))
    assert centred.value == pytest.approx(0.3)
    off = value("drivable_area", drive(np.zeros(3), y=half_lane + 0.5 - half_car, v=0.0))
    assert off.value == pytest.approx(0.3 - 0.5)
    assert off.first_violation == 0
    # on the neighbouring lane the ego is within the drivable area again
    west = Lane(id="west", centerline=Polyline(np.array([[1000.0, 3.5], [-1000.0, 3.5]])), width=3.5)
    assert value("drivable_area", drive(np.zeros(3), y=1.75, v=0.0, lanes=(EAST, west))).value == pytest.approx(0.3)


def test_driving_direction_is_nuplans_6_m_plus_the_last_seconds_movement_along_the_lane():
    west = drive(-10.0 * DT * np.arange(30), yaw=np.pi, v=10.0)
    result = value("driving_direction", west)
    # 1 m a frame the wrong way, summed over nuPlan's window of the frame and the 10 before it
    assert result.value == pytest.approx(6.0 - 11.0)
    assert result.first_violation == 7
    assert value("driving_direction", drive(10.0 * DT * np.arange(30), v=10.0)).value == pytest.approx(6.0)


def test_progress_is_the_share_of_the_ground_truths_progress_along_the_route():
    truth = drive(10.0 * DT * np.arange(51), v=10.0)
    stopped = value("progress", drive(np.zeros(51), v=0.0), truth)
    # nuPlan's ratio, each progress at least 2 m: 2 / 50 at the end; under 0.2 from 10 m of the truth's on
    assert stopped.per_frame[-1] == pytest.approx(2.0 / 50.0 - 0.2)
    assert stopped.first_violation == 11
    assert value("progress", truth, truth).value == pytest.approx(0.8)
    halfway = value("progress", drive(5.0 * DT * np.arange(51), v=5.0), truth)
    assert halfway.per_frame[-1] == pytest.approx(0.5 - 0.2)
    # a rollout that ended early (a contact) is compared at its own frames
    ended = value("progress", drive(np.zeros(21), v=0.0), truth)
    assert ended.per_frame.size == 21 and ended.per_frame[-1] == pytest.approx(2.0 / 20.0 - 0.2)


# ---------------------------------------------------------------- rules read from a rollout

SCENARIO = build_scenario(FOLLOW_SPEC)
T, N = SCENARIO.agents.shape


class Straight:
    """Drives straight on at `speed`; `fail_at` a frame from which it answers None, `fallback_at` frames
    it says its solver failed on (its stats())."""

    def __init__(self, speed=8.0, fail_at=None, fallback_at=()):
        self.speed, self.fail_at, self.fallback_at, self.failures, self.k = speed, fail_at, fallback_at, 0, 0

    def reset(self):
        self.failures, self.k = 0, 0

    def stats(self):
        return PlannerStats(failures=self.failures, solve_times=())

    def plan(self, t, ego, tracks):
        k, self.k = self.k, self.k + 1
        if k == self.fail_at:
            return None
        self.failures += k in self.fallback_at
        times = t + DT * np.arange(30)
        return Trajectory(t=times, x=ego.x + self.speed * (times - t), y=np.full(30, ego.y), yaw=np.zeros(30))


def rolled(planner, **config):
    config = RolloutConfig(**config)
    result = rollout(SCENARIO, PerceptionErrors.none(T, N).with_drop(0, 0, T - 1), Tracker(), planner, config)
    return result, rule_inputs(result, SCENARIO, config)


def test_the_collision_rules_are_the_rollouts_own_figures():
    result, inputs = rolled(Straight(speed=12.0))  # faster than the lead, it drives into it
    collision = evaluate(rule_class("collision")(), inputs)
    assert collision.value == result.min_signed_distance < 0.0
    assert collision.first_violation == result.num_frames - 1
    judged, _ = rolled(Straight(speed=12.0), at_fault_only=True)
    assert evaluate(rule_class("at_fault_collision")(), inputs).value == judged.margin


def test_planner_failure_is_the_frame_without_a_plan_or_with_the_planners_fallback():
    result, inputs = rolled(Straight(fail_at=5), stop_at_collision=False)
    assert result.inconclusive is not None
    failed = evaluate(rule_class("planner_failure")(), inputs)
    assert (failed.first_violation, failed.value, inputs.num_frames) == (5, -1.0, 6)
    result, inputs = rolled(Straight(fallback_at=(3, 7)), stop_at_collision=False)
    assert result.fallback_frames == (3, 7)
    fallback = evaluate(rule_class("planner_failure")(), inputs)
    assert np.flatnonzero(fallback.per_frame < 0).tolist() == [3, 7]
    _, fine = rolled(Straight(), stop_at_collision=False)
    assert evaluate(rule_class("planner_failure")(), fine).value == 1.0


def test_the_bundled_ground_truth_violates_no_rule(idm_bundled):
    name, scenario, params_path = idm_bundled
    stack = Stack(scenario, core_configs(load_params(params_path)))
    result = stack.rollout(PerceptionErrors.none(*scenario.agents.shape))
    inputs = rule_inputs(result, scenario, stack.config)
    values = {rule: evaluate(rule_class(rule)(), inputs, inputs) for rule in RULES}
    assert not [(rule, v.value, v.first_violation) for rule, v in values.items() if v.violated], name


def test_a_braking_that_ends_the_drive_is_read_at_its_rate_not_overstated_by_the_filter_s_edge():
    """A speed falling at exactly 3.0 m/s^2 over the last 5 frames: nuPlan's filter, evaluated at the end of its
    edge window, read -4.53 m/s^2 there (a hard and a phantom braking the ego never did); held from the last
    centred window, no frame reads beyond the braking's own rate."""
    from advperc_ros.core.rules.motion import longitudinal_acceleration

    v = np.concatenate([np.full(20, 10.0), 10.0 - 0.3 * np.arange(1, 6)])
    inputs = drive(np.cumsum(v) * DT, v=v)
    acceleration = longitudinal_acceleration(inputs)
    assert acceleration.min() >= -3.0 - 1e-6 and acceleration[-1] == acceleration[-1 - 4]
    assert not value("hard_braking", inputs).violated
