"""The paper's Algorithm 1 (heuristic bisection) and Algorithm 2 (random search) (README, "Search")."""

import copy
from collections import Counter
import dataclasses
import math
from types import SimpleNamespace

import numpy as np
import pytest

from advperc_ros.core.perception_errors import PerceptionErrors
from advperc_ros.core.planners.base import PlanningContext
from advperc_ros.core.planners.idm import IDMPlanner
from advperc_ros.core.rollout import rollout
from advperc_ros.core.scenario_spec import build_scenario
from advperc_ros.core.search.heuristic import heuristic_search, narrowing, run_lockstep, run_one
from advperc_ros.core.search.diagnosis import inconclusive_search
from advperc_ros.core.search.problem import AttackProblem, LogRow, Phase
from advperc_ros.exceptions import BudgetSpent, GroundTruthFails
from advperc_ros.core.search.random_search import RandomSearchConfig, propose, random_search
from advperc_ros.core.tracker import Tracker
from toy_scenarios import FOLLOW_SPEC

ITERATIONS = 3

BASE_SPEC = FOLLOW_SPEC


def spec_with_lead_speed(speed):
    spec = copy.deepcopy(BASE_SPEC)
    spec["agents"][0]["speed"] = speed
    return spec


SPECS = {
    "constant_lead": BASE_SPEC,
    "braking_lead": spec_with_lead_speed([[0.0, 8.0], [3.0, 8.0], [4.5, 2.0]]),
}


class Recorder:
    """The stack under attack, recording every error tensor it is asked to roll out."""

    def __init__(self, scenario):
        self.scenario = scenario
        context = PlanningContext(route=scenario.route, lanes=scenario.lanes, dt=scenario.dt,
                                  ego_length=4.6, ego_width=1.9)
        self.tracker = Tracker()
        self.planner = IDMPlanner(context, target_speed=14.0)
        self.calls = []  # (errors copy, result)

    def __call__(self, errors):
        result = rollout(self.scenario, errors, self.tracker, self.planner)
        self.calls.append((errors.copy(), result))
        return result


def make_problem(spec, objective="nds_t"):
    scenario = build_scenario(spec)
    recorder = Recorder(scenario)
    rows = []
    problem = AttackProblem(scenario, recorder, objective, on_rollout=rows.append)
    return problem, recorder, rows


def dropped_segment(errors):
    """(agent column, start, end) of the only dropped segment, or None; asserts the tensor is a pure drop."""
    assert not errors.dx.any() and not errors.dy.any() and not errors.dyaw.any()
    cols = np.flatnonzero(errors.fn.any(axis=0))
    if cols.size == 0:
        return None
    assert cols.size == 1, "a heuristic tensor drops one agent"
    frames = np.flatnonzero(errors.fn[:, cols[0]])
    assert np.array_equal(frames, np.arange(frames[0], frames[-1] + 1)), "one contiguous segment"
    return int(cols[0]), int(frames[0]), int(frames[-1])


def reference_heuristic(num_frames, num_agents, ask, iterations=ITERATIONS):
    """Algorithm 1 written out from the paper. ask(agent, start, end) rolls the drop out and answers
    (collided, frames rolled out). Returns the failing segment per influential agent."""
    modes = {}
    for j in range(num_agents):
        collided, frames = ask(j, 0, num_frames - 1)
        if not collided:
            continue
        failing = (0, num_frames - 1)
        # largest start such that dropping [start, T-1] still fails
        lo, hi = 0, num_frames
        for _ in range(iterations):
            if hi - lo <= 1:
                break
            mid = (lo + hi) // 2
            c, k = ask(j, mid, num_frames - 1)
            if c:
                lo, frames, failing = mid, k, (mid, num_frames - 1)
            else:
                hi = mid
        start = lo
        # smallest end such that dropping [start, end] still fails; nothing after the collision matters
        lo, hi = start - 1, min(num_frames, frames) - 1
        for _ in range(iterations):
            if hi - lo <= 1:
                break
            mid = (lo + hi) // 2
            c, k = ask(j, start, mid)
            if c:
                hi, failing = mid, (start, mid)
            else:
                lo = mid
        modes[j] = failing
    return modes


@pytest.fixture(scope="module", params=sorted(SPECS))
def heuristic_run(request):
    problem, recorder, rows = make_problem(SPECS[request.param])
    modes = heuristic_search(problem, ITERATIONS).modes
    return problem, recorder, rows, modes


# ---------------------------------------------------------------- Algorithm 1

def test_ground_truth_failure_stops_the_search():
    """A stationary car 8 m ahead of an ego at 15 m/s: the ground truth already collides."""
    spec = copy.deepcopy(BASE_SPEC)
    spec["ego"]["speed"] = 15.0
    spec["agents"][0] = {"id": 1, "lane": "east", "start_s": 108.0, "speed": 0.0}
    problem, recorder, _ = make_problem(spec)
    with pytest.raises(GroundTruthFails, match="already collides"):
        heuristic_search(problem, ITERATIONS)
    assert len(recorder.calls) == 1 and len(problem.log) == 1
    assert dropped_segment(recorder.calls[0][0]) is None
    assert problem.log[0].collided and not problem.log[0].accepted


def test_inconclusive_ground_truth_stops_the_search():
    problem, recorder, _ = make_problem(BASE_SPEC)

    class Broken:
        def reset(self):
            pass

        def plan(self, t, ego, tracks):
            raise RuntimeError("no plan today")

    recorder.planner = Broken()
    with pytest.raises(GroundTruthFails, match="inconclusive"):
        heuristic_search(problem, ITERATIONS)
    assert len(recorder.calls) == 1


def test_only_the_lead_is_a_failure_mode(heuristic_run):
    problem, recorder, _, modes = heuristic_run
    assert len(modes) == 1
    mode = modes[0]
    assert mode.adversarial
    column, start, end = dropped_segment(mode.errors)
    assert column == 0  # the lead, not the oncoming car
    assert 0 < start <= end
    # the oncoming car's full drop was tried and is harmless
    tried = [dropped_segment(e) for e, _ in recorder.calls]
    assert (1, 0, problem.scenario.num_frames - 1) in tried
    oncoming = [r for (e, r), seg in zip(recorder.calls, tried) if seg and seg[0] == 1]
    assert len(oncoming) == 1 and not oncoming[0].collided


def test_bisection_matches_reference(heuristic_run):
    problem, recorder, _, modes = heuristic_run
    num_frames, num_agents = problem.scenario.agents.shape
    calls = iter(recorder.calls[1:])
    asked = []

    def ask(j, start, end):
        asked.append((j, start, end))
        errors, result = next(calls)
        return result.collided, result.num_frames

    assert dropped_segment(recorder.calls[0][0]) is None  # ground truth first
    expected = reference_heuristic(num_frames, num_agents, ask)
    evaluated = [dropped_segment(e) for e, _ in recorder.calls[1:]]
    assert evaluated == asked
    assert next(calls, None) is None  # nothing beyond what the reference asked for
    # both bisections ran (they are not cut short in these scenarios) and gave both answers
    assert len(evaluated) == 1 + 2 * ITERATIONS + 1
    answers = {r.collided for _, r in recorder.calls[2 : 2 + ITERATIONS]}
    assert answers == {True, False}
    # the failure mode is the last failing segment the reference found
    assert set(expected) == {0}
    assert dropped_segment(modes[0].errors) == (0, *expected[0])


def test_every_rollout_is_logged_in_order(heuristic_run):
    problem, recorder, rows, _ = heuristic_run
    log = problem.log
    assert len(log) == len(recorder.calls)
    assert [row.rollout for row in log] == list(range(1, len(log) + 1))
    assert rows == log  # the callback saw every row
    phases = [row.phase for row in log]
    assert phases[0] == "ground_truth" and phases[1] == "heuristic_drop" and phases[-1] == "heuristic_drop"
    assert phases[2 : 2 + ITERATIONS] == ["heuristic_start"] * ITERATIONS
    assert phases[2 + ITERATIONS : 2 + 2 * ITERATIONS] == ["heuristic_end"] * ITERATIONS
    assert [row.agent for row in log] == [-1] + [1] * (1 + 2 * ITERATIONS) + [7]  # agent ids, not slots
    for row, (_, result) in zip(log, recorder.calls):
        assert row.collided == result.collided
        assert row.min_signed_distance == result.min_signed_distance
        assert row.accepted == (result.collided and row.phase != "ground_truth")


def test_best_is_the_best_adversarial_evaluation(heuristic_run):
    problem, _, _, modes = heuristic_run
    adversarial = [row.metric for row in problem.log if row.collided]
    assert problem.best is not None and problem.best.adversarial
    assert problem.best.metric == max(adversarial)
    assert problem.best.metric >= modes[0].metric
    _check_best_metric_column(problem.log)


def _check_best_metric_column(log):
    running = -math.inf
    previous = -math.inf
    for row in log:
        if row.collided:
            running = max(running, row.metric)
        if running == -math.inf:
            assert math.isnan(row.best_metric)
        else:
            assert row.best_metric == running
            assert row.best_metric >= previous
            previous = row.best_metric


def test_unknown_objective_rejected():
    scenario = build_scenario(BASE_SPEC)
    with pytest.raises(ValueError, match="pem"):
        AttackProblem(scenario, Recorder(scenario), "pem")


# ---------------------------------------------------------------- Algorithm 2: proposals

def proposal_change(parent, child, frames, cfg):
    """Asserts child is one proposal away from parent; returns (agent, flipped frames, offset)."""
    flipped = parent.fn & ~child.fn
    assert not (child.fn & ~parent.fn).any(), "a proposal never adds drops"
    same = ~flipped
    for name in ("dx", "dy", "dyaw"):
        assert np.array_equal(getattr(parent, name)[same], getattr(child, name)[same]), f"{name} changed off the flip"
    if not flipped.any():
        return None
    cols = np.flatnonzero(flipped.any(axis=0))
    assert cols.size == 1, "one agent per proposal"
    j = int(cols[0])
    rows = np.flatnonzero(flipped[:, j])
    assert rows[-1] < frames, "only frames of the previous rollout"
    # a segment: every frame dropped in the parent between the first and last flipped one is flipped
    span = np.arange(rows[0], rows[-1] + 1)
    np.testing.assert_array_equal(rows, span[parent.fn[span, j]])
    dx, dy = child.dx[rows, j], child.dy[rows, j]
    assert np.all(dx == dx[0]) and np.all(dy == dy[0]), "one constant offset per proposal"
    assert math.hypot(dx[0], dy[0]) <= cfg.max_offset
    return j, rows, (dx[0], dy[0]), child.dyaw[rows, j]


def test_propose_flips_only_dropped_frames_within_the_rollout():
    cfg = RandomSearchConfig(max_offset=5.0, yaw_std=0.1)
    base = PerceptionErrors.none(101, 3)
    base.fn[20:, 0] = True
    base.fn[5:31, 1] = True
    base.fn[40:46, 1] = True  # a second dropped stretch of the same agent
    base.dx[0:20, 0] = 1.25  # earlier accepted flips keep their offsets
    base.dyaw[0:20, 0] = 0.05
    rng = np.random.default_rng(7)
    agents, magnitudes, angles, yaw_noise, lengths = set(), [], [], [], []
    for _ in range(2000):
        child = propose(base, 60, rng, cfg)
        change = proposal_change(base, child, 60, cfg)
        if change is None:
            continue
        j, rows, (dx, dy), dyaw = change
        agents.add(j)
        magnitudes.append(math.hypot(dx, dy))
        angles.append(math.atan2(dy, dx))
        yaw_noise.extend(dyaw)
        lengths.append(rows.size)
    assert agents == {0, 1}
    magnitudes, angles, yaw_noise = np.array(magnitudes), np.array(angles), np.array(yaw_noise)
    # magnitude U(0, 5), direction uniform, yaw noise N(0, 0.1)
    assert magnitudes.max() > 4.9 and magnitudes.min() < 0.1
    assert magnitudes.mean() == pytest.approx(2.5, abs=0.15)
    assert np.histogram(angles, bins=4, range=(-np.pi, np.pi))[0].min() > 0.2 * len(angles)
    assert np.std(yaw_noise) == pytest.approx(0.1, rel=0.05)
    assert abs(np.mean(yaw_noise)) < 0.01
    assert max(lengths) >= 40 and min(lengths) == 1  # segments from single frames to the whole span


def test_propose_without_drops_in_the_rollout_gives_nothing():
    cfg = RandomSearchConfig()
    base = PerceptionErrors.none(50, 2)
    base.fn[30:, 0] = True
    rng = np.random.default_rng(0)
    assert propose(base, 30, rng, cfg) is None
    assert propose(PerceptionErrors.none(50, 2), 50, rng, cfg) is None
    child = propose(base, 31, rng, cfg)
    assert child is not None and not child.fn[30, 0] and child.fn[31:, 0].all()


def test_propose_does_not_modify_its_input():
    base = PerceptionErrors.none(40, 1).with_drop(0, 5, 30)
    before = base.copy()
    propose(base, 40, np.random.default_rng(1), RandomSearchConfig())
    assert base.equals(before)


# ---------------------------------------------------------------- Algorithm 2: the search

SEARCH_CFG = RandomSearchConfig(steps=8, proposals=20)


@pytest.fixture(scope="module")
def initial_mode():
    problem, _, _ = make_problem(BASE_SPEC)
    return heuristic_search(problem, ITERATIONS).modes[0]


def run_random(initial, seed):
    problem, recorder, _ = make_problem(BASE_SPEC)
    final = random_search(problem, initial, np.random.default_rng(seed), SEARCH_CFG)
    return problem, recorder, final


@pytest.fixture(scope="module")
def random_runs(initial_mode):
    return run_random(initial_mode, 0), run_random(initial_mode, 0), run_random(initial_mode, 1)


def test_same_seed_same_attack(random_runs):
    (_, rec_a, final_a), (_, rec_b, final_b), (_, rec_c, _) = random_runs
    assert len(rec_a.calls) > 0
    assert len(rec_a.calls) == len(rec_b.calls)
    for (ea, ra), (eb, rb) in zip(rec_a.calls, rec_b.calls):
        assert ea.equals(eb)
        assert np.array_equal(ra.ego, rb.ego)
    assert final_a.errors.equals(final_b.errors)
    # and the seed matters
    assert not (len(rec_a.calls) == len(rec_c.calls)
                and all(ea.equals(ec) for (ea, _), (ec, _) in zip(rec_a.calls, rec_c.calls)))


def test_random_search_only_accepts_colliding_rollouts(random_runs, initial_mode):
    for problem, recorder, final in random_runs:
        current = initial_mode
        collided_seen = not_collided_seen = False
        for (errors, result), row in zip(recorder.calls, problem.log):
            # every proposal rolled out derives from the last accepted (colliding) tensor ...
            proposal_change(current.errors, errors, current.rollout.num_frames, SEARCH_CFG)
            # ... and improved the metric judged on that tensor's rollout
            assert problem.metric(errors, current.rollout) > current.metric
            assert row.phase == "random" and row.accepted == result.collided
            if result.collided:
                collided_seen = True
                current = dataclasses.replace(current, errors=errors, rollout=result, metric=row.metric)
            else:
                not_collided_seen = True
        assert collided_seen and not_collided_seen  # both branches exercised
        assert final.adversarial
        assert final.errors.equals(current.errors)


def test_random_search_best_metric_non_decreasing(random_runs, initial_mode):
    for problem, _, final in random_runs:
        _check_best_metric_column(problem.log)
        assert problem.best.metric >= final.metric
        assert problem.best.metric > initial_mode.metric  # it made progress over the heuristic


def test_random_search_metric_is_the_objective(random_runs):
    problem, recorder, _ = random_runs[0]
    for (errors, result), row in zip(recorder.calls, problem.log):
        scores = problem.scores(errors, result)
        assert row.metric == scores.nds_t
        assert row.nds == scores.nds


# ----- refine (beyond the paper) ------------------------------------------------------------------


def test_dropped_runs_matches_a_naive_scan():
    from advperc_ros.core.search.refine import dropped_runs

    rng = np.random.default_rng(3)
    for _ in range(50):
        fn = rng.random((30, 4)) < 0.4
        naive = []
        for j in range(fn.shape[1]):
            k = 0
            while k < fn.shape[0]:
                if fn[k, j]:
                    end = k
                    while end + 1 < fn.shape[0] and fn[end + 1, j]:
                        end += 1
                    naive.append((j, k, end))
                    k = end + 1
                else:
                    k += 1
        assert dropped_runs(fn) == naive


def test_refine_keeps_only_failing_rollouts_and_restores_perfect_detections():
    from advperc_ros.core.search.refine import refine_drops

    problem, _, _ = make_problem(BASE_SPEC)
    best = max(heuristic_search(problem, ITERATIONS).modes, key=lambda m: m.metric)
    before = len(problem.log)
    refined = refine_drops(problem, best, iterations=4)
    rows = problem.log[before:]
    assert 0 < len(rows) <= 4 and all(row.phase == "refine" for row in rows)
    assert refined.adversarial and refined.metric >= best.metric
    changed = refined.errors.fn != best.errors.fn
    assert not np.any(refined.errors.fn & ~best.errors.fn)  # only ever re-detects
    assert np.all(refined.errors.dx[changed] == 0.0) and np.all(refined.errors.dyaw[changed] == 0.0)
    best_so_far = [row.best_metric for row in problem.log if not np.isnan(row.best_metric)]
    assert best_so_far == sorted(best_so_far)


def test_a_budget_spent_within_the_heuristic_reports_its_failing_rollout_as_the_heuristic_s():
    """The lead's drop collides at rollout 2, the budget ends at 3 mid-bisection: the report needs a
    heuristic row for the attack it reports (it used to be None, and writing report.md failed)."""
    from advperc_ros.core.search.config import SearchConfig
    from advperc_ros.core.search.pipeline import run_search

    problem, _, _ = make_problem(BASE_SPEC)
    result = run_search(problem, SearchConfig(budget=3, method="paper"))  # one rollout at a time
    assert len(problem.log) == 3 and result.best is not None
    assert result.heuristic is result.best and result.heuristic.adversarial


class WindowStack:
    """A stand-in problem whose slot j collides exactly when its drop covers CRITICAL[j] (frames,
    inclusive): bisection has one right answer per slot. Records the size of every batch."""

    CRITICAL = {0: (18, 21), 2: (27, 33)}
    FRAMES = 40

    def __init__(self, budget=None):
        self.scenario = SimpleNamespace(num_frames=self.FRAMES, agents=SimpleNamespace(shape=(self.FRAMES, 3)),
                                        agent_id=lambda j: 10 + j)
        self.budget, self.log, self.batches = budget, [], []

    def evaluate(self, errors, phase, agent):
        if self.budget is not None and len(self.log) >= self.budget:
            raise BudgetSpent("spent")
        first, last = self.CRITICAL[agent - 10]
        trial = SimpleNamespace(errors=errors, adversarial=bool(errors.fn[first : last + 1, agent - 10].all()),
                                rollout=SimpleNamespace(inconclusive=None, num_frames=self.FRAMES))
        self.log.append((agent, trial.adversarial))
        return trial

    def evaluate_many(self, batch):
        if self.budget is not None and len(self.log) + len(batch) > self.budget:
            raise BudgetSpent("spent")
        self.batches.append(len(batch))
        return [self.evaluate(*request) for request in batch]

    def whole_drop(self, j):
        errors = PerceptionErrors.none(self.FRAMES, 3)
        errors.fn[:, j] = True
        return SimpleNamespace(errors=errors, adversarial=True, rollout=SimpleNamespace(inconclusive=None,
                                                                                      num_frames=self.FRAMES))

    def narrowings(self, iterations):
        return [narrowing(self.scenario, {j: (0, self.FRAMES - 1)}, j, iterations, self.whole_drop(j)) for j in (0, 2)]


@pytest.mark.parametrize("iterations", [3, 6])
def test_bisections_in_lockstep_narrow_as_they_do_one_at_a_time(iterations):
    """The guided method's heuristic runs the influential agents' bisections together, a batch a
    step: every segment and failing rollout is the one bisecting that agent alone finds, with the
    same rollouts in all, in half the steps."""
    alone = WindowStack()
    one_by_one = [run_one(alone, steps) for steps in alone.narrowings(iterations)]
    together = WindowStack()
    lockstep = run_lockstep(together, together.narrowings(iterations))
    assert [segments for segments, _ in lockstep] == [segments for segments, _ in one_by_one]
    for (_, a), (_, b) in zip(lockstep, one_by_one):
        assert np.array_equal(a.errors.fn, b.errors.fn)
    assert sorted(together.log) == sorted(alone.log)
    per_agent = sorted(Counter(agent for agent, _ in alone.log).values())  # a bisection stops once its bounds meet
    assert together.batches == [2] * per_agent[0] + [1] * (per_agent[1] - per_agent[0])
    if iterations == 3:
        assert per_agent == [6, 6]
    if iterations == 6:  # fine enough to find the critical frames themselves
        assert [segments[j] for (segments, _), j in zip(lockstep, (0, 2))] == [(18, 21), (27, 33)]


def test_a_lockstep_wave_is_cut_to_the_rollouts_left():
    """With 3 rollouts left, a wave of 2 then a wave of 1, then the budget ends the search."""
    stack = WindowStack(budget=3)
    with pytest.raises(BudgetSpent):
        run_lockstep(stack, stack.narrowings(3))
    assert stack.batches == [2, 1] and len(stack.log) == 3


def _row(rollout: int, collided: bool = False, inconclusive: str = "") -> LogRow:
    return LogRow(rollout, Phase.HEURISTIC_DROP, rollout, 0.5, 0.9, 0.5, 1.0, collided, inconclusive, None, collided,
                  float("nan"))


def test_a_search_mostly_inconclusive_cannot_say_no_collision():
    """More than half the rollouts inconclusive and no collision: the null result is not shown, and the
    message names the most frequent cause; half, or any real collision, and the result stands."""
    superseded = [_row(k, inconclusive=f"frame {k}: superseded by rollout {k + 7}") for k in range(2, 6)]
    text = inconclusive_search([_row(1), *superseded, _row(6, inconclusive="planner raised ValueError")])
    assert text == ("5 of 6 rollouts were inconclusive, so the search cannot say that no collision exists; the most "
                    "frequent cause (4 rollouts): frame 2: superseded by rollout 9")
    assert inconclusive_search([_row(1), _row(2), *superseded[:2]]) is None  # half
    assert inconclusive_search([_row(1), _row(2, collided=True), *superseded]) is None  # a collision found stands
