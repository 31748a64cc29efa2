"""The approach phase (README, "Search"): when no drop collides, cars shown displaced until the ego does."""

import dataclasses

import numpy as np
import pytest

from advperc_ros.core.perception_errors import PerceptionErrors
from advperc_ros.core.planners.base import Trajectory
from advperc_ros.core.rollout import RolloutConfig, RolloutResult, rollout
from advperc_ros.core.scenario_spec import build_scenario
from advperc_ros.core.search import approach
from advperc_ros.core.search.config import SearchConfig, bound
from advperc_ros.core.search.pipeline import run_search
from advperc_ros.core.search.problem import AttackProblem, Evaluation, Phase
from advperc_ros.core.tracker import Tracker
from test_search import make_problem
from toy_scenarios import FOLLOW_SPEC, PLATOON_SPEC

LANE_Y = -1.75  # the ego's lane; the lane beside it is at +1.75
SPEED = 8.0
# The ego drives east in its lane; a car drives beside it in the left lane, 3 m ahead, at its speed; two
# more are far ahead and far behind. A planner that changes lanes away from a car it sees ahead in its
# own lane (`Swerver`) sees none with perfect perception, nor with any car hidden: no drop collides.
# Shown 2-5 m to the right, the car beside looks like one ahead in the ego's lane, and the ego swerves
# into the real one.
SWERVE_SPEC = {
    "name": "swerve",
    "dt": 0.1,
    "duration": 6.0,
    "lanes": [
        {"id": "east", "centerline": [[-100.0, LANE_Y], [500.0, LANE_Y]], "width": 3.5},
        {"id": "left", "centerline": [[-100.0, -LANE_Y], [500.0, -LANE_Y]], "width": 3.5},
    ],
    "ego": {"route": ["east"], "start_s": 100.0, "speed": SPEED},
    "agents": [
        {"id": 3, "lane": "left", "start_s": 103.0, "speed": SPEED, "size": [4.6, 1.9, 1.6]},  # beside
        {"id": 9, "lane": "east", "start_s": 300.0, "speed": SPEED, "size": [4.6, 1.9, 1.6]},  # far ahead
        {"id": 5, "lane": "left", "start_s": 40.0, "speed": SPEED, "size": [4.6, 1.9, 1.6]},  # far behind
    ],
}


class Swerver:
    """Constant speed in its lane; once it sees a track up to 20 m ahead in that lane, it changes to
    the left lane at 1.5 m/s. With `fail_at`, it raises once it has moved that far to the left (a
    planner that fails mid-manoeuvre: the rollout is inconclusive, though nearer the car beside)."""

    def __init__(self, fail_at: float | None = None):
        self.fail_at = fail_at
        self.swerving = False

    def reset(self):
        self.swerving = False

    def plan(self, t, ego, tracks):
        ahead = (tracks["x"] - ego.x > 0.0) & (tracks["x"] - ego.x < 20.0) & (np.abs(tracks["y"] - LANE_Y) < 1.5)
        self.swerving = self.swerving or bool(ahead.any())
        if self.fail_at is not None and ego.y > LANE_Y + self.fail_at:
            raise RuntimeError("lost mid-manoeuvre")
        times = t + 0.1 * np.arange(31)
        x = ego.x + SPEED * (times - t)
        y = np.minimum(ego.y + 1.5 * (times - t), -LANE_Y) if self.swerving else np.full(times.size, ego.y)
        yaw = np.arctan2(np.gradient(y), np.gradient(x))
        return Trajectory(t=times, x=x, y=y, yaw=yaw)


def swerve_problem(fail_at: float | None = None, spec: dict = SWERVE_SPEC) -> AttackProblem:
    scenario = build_scenario(spec)
    tracker, planner = Tracker(), Swerver(fail_at)
    config = RolloutConfig(at_fault_only=True)
    return AttackProblem(scenario, lambda errors: rollout(scenario, errors, tracker, planner, config), "nds_t")


CONFIG = SearchConfig(random=dataclasses.replace(SearchConfig().random, steps=5), refine_iterations=2, method="paper")


@pytest.fixture(scope="module")
def swerve():
    problem = swerve_problem()
    return problem, run_search(problem, CONFIG)


def phases(log):
    return [str(row.phase) for row in log]


def test_no_drop_collides_but_a_displaced_car_does(swerve):
    problem, result = swerve
    heuristic_rows = [row for row in problem.log if row.phase in ("heuristic_drop", "joint")]
    assert heuristic_rows and not any(row.collided for row in heuristic_rows)  # blind included
    assert result.joint is not None and not result.joint.blind.adversarial
    found = result.approach.collision
    assert found is not None and found.adversarial and not found.rollout.inconclusive
    assert result.heuristic is found and result.best.metric >= found.metric
    # the collision is with the car beside, at the ego's fault, and some car is shown displaced
    frame, slot = found.rollout.closest_approach()
    assert problem.scenario.agent_id(slot) == 3 and not found.rollout.excused[frame, slot]
    assert (found.errors.dx != 0).any() or (found.errors.dy != 0).any()
    assert phases(problem.log)[len(heuristic_rows) + 1 :] == ["approach"] * result.approach.rollouts  # nothing
    # dropped: neither the random search nor refine has a proposal


def test_the_guided_search_trades_the_displacement_back():
    problem = swerve_problem()
    result = run_search(problem, dataclasses.replace(CONFIG, method="guided"))
    assert result.approach.collision is not None and "guided" in phases(problem.log)
    assert result.best.metric >= result.approach.collision.metric and result.best.adversarial


def test_each_step_keeps_a_conclusive_candidate_of_lower_margin_only(swerve):
    problem, result = swerve
    rows = [row for row in problem.log if row.phase == Phase.APPROACH]
    assert 1 <= result.approach.rollouts == len(rows) <= approach.worst_case(CONFIG.approach_steps, 3)
    assert result.approach.closest.rollout.margin < result.approach.start.rollout.margin


def test_the_margin_counts_only_what_the_verdict_counts():
    """A contact that is not the ego's fault is not in the margin, and the margin is below 0 exactly
    when the verdict is a collision."""
    problem = swerve_problem()
    r = problem.evaluate(PerceptionErrors.none(*problem.scenario.agents.shape), Phase.GROUND_TRUTH).rollout
    assert r.margin == r.min_signed_distance > 0 and not r.collided
    excused = dataclasses.replace(r, distances=r.distances.copy(), excusable=np.zeros_like(r.distances, dtype=bool))
    excused.distances[5, 0], excused.excusable[5, 0] = -0.3, True
    assert excused.min_signed_distance == -0.3 and excused.margin == r.margin and not excused.collided
    excused.excusable[5, 0] = False
    assert excused.margin == -0.3 and excused.collided


def test_the_phase_stays_within_its_bound_and_the_budget(swerve):
    problem, result = swerve
    num_agents = problem.scenario.agents.shape[1]
    assert len(problem.log) <= bound(CONFIG, num_agents, joint=True, approach=True)
    assert bound(CONFIG, num_agents, joint=True, approach=True) == bound(CONFIG, num_agents, joint=True) + \
        CONFIG.approach_steps + 2
    heuristic = sum(1 for row in problem.log if str(row.phase) in ("ground_truth", "heuristic_drop", "joint"))
    for budget in (heuristic + 1, heuristic + 3):
        small = swerve_problem()
        run_search(small, dataclasses.replace(CONFIG, budget=budget))
        assert len(small.log) <= budget


def test_same_seed_same_attack_bit_for_bit(swerve):
    problem, result = swerve
    again = swerve_problem()
    second = run_search(again, CONFIG)
    np.testing.assert_equal([dataclasses.astuple(r) for r in problem.log], [dataclasses.astuple(r) for r in again.log])
    assert second.best.errors.equals(result.best.errors)


def test_inconclusive_rollouts_are_never_kept():
    """The planner fails half-way into the lane change: those rollouts came nearer the car beside
    than anything conclusive, yet the phase keeps none of them and finds no collision."""
    problem = swerve_problem(fail_at=0.8)
    result = run_search(problem, CONFIG)
    rows = [row for row in problem.log if row.phase == Phase.APPROACH]
    failed = [row for row in rows if row.inconclusive]
    assert failed and min(row.min_signed_distance for row in failed) < result.approach.start.rollout.margin
    assert result.best is None and result.approach.collision is None
    assert result.approach.closest is result.approach.start and len(rows) == CONFIG.approach_patience


@pytest.mark.parametrize("spec", [FOLLOW_SPEC, PLATOON_SPEC], ids=["single drop", "joint drop"])
def test_the_phase_does_not_run_when_a_drop_collides(spec):
    def log(steps):
        problem, recorder, _ = make_problem(spec)
        result = run_search(problem, dataclasses.replace(CONFIG, approach_steps=steps))
        return result, [dataclasses.astuple(row) for row in problem.log], recorder.calls

    (on, log_on, calls_on), (off, log_off, calls_off) = log(30), log(0)
    assert on.approach is None and "approach" not in {row[1] for row in log_on}
    np.testing.assert_equal(log_on, log_off)
    assert all(a.equals(b) for (a, _), (b, _) in zip(calls_on, calls_off)) and len(calls_on) == len(calls_off)
    assert on.best.errors.equals(off.best.errors)


def test_switched_off_nothing_runs():
    problem = swerve_problem()
    result = run_search(problem, dataclasses.replace(CONFIG, approach_steps=0))
    assert result.best is None and result.approach is None and "approach" not in phases(problem.log)
    assert approach.worst_case(0, 3) == 0 and approach.worst_case(30, 83) == 30 + 7


def evaluation(closest: list[float], excusable: list[bool] | None = None):
    """An evaluation whose rollout comes `closest[j]` near car j at one frame (the excusable cars' as
    near, but behind the ego: no step towards its fault)."""
    distances = np.array([closest, [50.0] * len(closest)])
    rollout_result = RolloutResult(ego=np.zeros((2, 4)), distances=distances,
                                   excusable=None if excusable is None else np.array([excusable] * 2))
    return Evaluation(PerceptionErrors.none(2, len(closest)), rollout_result, None, 0.0)


@pytest.mark.parametrize("trial, current, expected", [
    ([0.50, 1.50, 9.0], [0.50, 2.00, 9.0], True),  # the nearest car as near, the next one nearer
    ([0.505, 1.50, 9.0], [0.50, 2.00, 9.0], True),  # under MIN_GAIN further from the nearest is a tie
    ([0.52, 1.00, 9.0], [0.50, 2.00, 9.0], False),  # 2 cm further from the nearest outweighs the next
    ([0.40, 3.00, 9.0], [0.50, 2.00, 9.0], True),  # nearer the nearest, whatever follows
    ([0.50, 2.00, 9.0], [0.50, 2.00, 9.0], False),  # no progress
    ([2.00, 0.50, 9.0], [0.50, 2.00, 9.0], False),  # the same margins on other cars: no progress
    ([0.50, 2.00, np.inf], [0.50, 2.00, 9.0], False),  # a car gone out of reach is no step nearer
])
def test_nearer_compares_each_cars_margin_nearest_first(trial, current, expected):
    assert approach.nearer(evaluation(trial), evaluation(current)) is expected
    if expected:
        assert not approach.nearer(evaluation(current), evaluation(trial))


def test_a_car_only_ever_behind_the_ego_is_neither_near_nor_progress():
    behind = [False, True, False]
    current, trial = evaluation([0.5, 2.0, 3.0], behind), evaluation([0.5, 0.1, 3.0], behind)
    assert not approach.nearer(trial, current)
    np.testing.assert_array_equal(approach.nearest(current, trial), [0, 2])


def test_hide_hides_a_segment_of_a_car_in_where_and_nothing_else():
    errors = PerceptionErrors.none(20, 3)
    errors.dx[:, 1], errors.dy[:, 1] = 2.0, -1.0  # car 1 shown displaced before: hidden frames lose it
    where = np.zeros((20, 3), dtype=bool)
    where[4:15, 1] = True
    rng = np.random.default_rng(0)
    spans = set()
    for _ in range(200):
        out = approach.hide(errors, rng, where)
        hidden = np.flatnonzero(out.fn[:, 1])
        assert not out.fn[:, [0, 2]].any() and hidden.size and 4 <= hidden[0] and hidden[-1] < 15
        np.testing.assert_array_equal(hidden, np.arange(hidden[0], hidden[-1] + 1))  # one segment
        assert (out.dx[hidden, 1] == 0).all() and (np.delete(out.dx[:, 1], hidden) == 2.0).all()
        spans.add((hidden[0], hidden[-1]))
    assert len(spans) > 20 and not errors.fn.any()  # segments vary; the input is left alone
    assert approach.hide(errors, rng, np.zeros((20, 3), dtype=bool)) is None


def test_patience_counts_from_the_last_step_nearer_and_steps_cap_the_phase(monkeypatch):
    """With every candidate nearer than the last, the phase runs to `steps`; with none, it gives up
    after `patience`; after a step nearer, `patience` more."""
    scripted: list[bool] = []
    monkeypatch.setattr(approach, "nearer", lambda trial, current: scripted.pop(0) if scripted else False)

    def rollouts(script, steps, patience):
        # no car beside the ego: it swerves into nothing, so no candidate collides
        spec = {**SWERVE_SPEC, "agents": [a for a in SWERVE_SPEC["agents"] if a["id"] != 3]}
        problem = swerve_problem(spec=spec)
        seen = [problem.evaluate(PerceptionErrors.none(*problem.scenario.agents.shape), Phase.GROUND_TRUTH)]
        scripted[:] = script  # one comparison per step
        return approach.approach(problem, seen, np.random.default_rng(0), CONFIG.random, steps, patience).rollouts

    assert rollouts([True] * 100, steps=12, patience=3) == 12
    assert rollouts([], steps=12, patience=3) == 3
    assert rollouts([False, True, False, False, True], steps=12, patience=3) == 5 + 3


def test_a_walk_stalled_from_a_phantom_goes_on_from_the_nearest_rollout_without_ghosts(monkeypatch):
    """A phantom obstacle's near miss may be a dead end that the paper's kinds' start is not: with a
    phantom nearest, the phase walks from it, and once that walk stalls it walks again from the nearest
    rollout showing no ghost, with the steps left; the nearer of the two walks' ends is its closest."""
    from advperc_ros.core.perception_errors import ERROR_KINDS, ErrorSpace
    from advperc_ros.core.search import phantom

    every_kind = ErrorSpace(kinds=ERROR_KINDS)
    spec = {**SWERVE_SPEC, "agents": [a for a in SWERVE_SPEC["agents"] if a["id"] != 3]}  # nothing to hit
    problem = swerve_problem(spec=spec)
    truth = problem.evaluate(every_kind.blank(*problem.scenario.agents.shape), Phase.GROUND_TRUTH)
    probe = phantom.probes(truth, problem.scenario.agents.shape, problem.scenario.dt, every_kind)[-1]
    probed = problem.evaluate(probe, Phase.PHANTOM)
    assert not probed.adversarial and "ghost" in probe.used_kinds(probed.rollout.num_frames)
    # the phantom is nearer than anything; no candidate of either walk is nearer than where it started
    monkeypatch.setattr(approach, "nearer", lambda trial, current: trial is probed and current is not probed)
    evaluate, shown = problem.evaluate, []

    def recording(errors, *args):
        shown.append("ghost" in errors.used_kinds(errors.shape[0]))
        return evaluate(errors, *args)

    monkeypatch.setattr(problem, "evaluate", recording)
    patience = 4
    result = approach.approach(problem, [truth, probed], np.random.default_rng(0), CONFIG.random, 30, patience)
    assert result.start is probed and result.closest is probed and result.rollouts == 2 * patience
    assert shown == [True] * patience + [False] * patience  # the phantom's walk, then the ground truth's
    # with the steps spent by the first walk, there is no second
    again = approach.approach(problem, [truth, probed], np.random.default_rng(0), CONFIG.random, patience, patience)
    assert again.rollouts == patience
    # without a phantom nearest, one walk as before
    monkeypatch.setattr(approach, "nearer", lambda trial, current: False)
    assert approach.approach(problem, [truth, probed], np.random.default_rng(0), CONFIG.random, 30, patience).rollouts \
        == patience
