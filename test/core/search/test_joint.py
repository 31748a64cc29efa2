"""Joint drops (README, "Search"): when no single agent's drop collides, a small set dropped together."""

import dataclasses

import numpy as np
import pytest

from advperc_ros.core.scenario_spec import build_scenario
from advperc_ros.core.search.heuristic import heuristic_search
from advperc_ros.core.search.joint import joint_drops, worst_case
from advperc_ros.core.search.config import SearchConfig, bound
from advperc_ros.core.search.pipeline import run_search
from advperc_ros.core.search.registry import METHODS
from advperc_ros.core.search.problem import AttackProblem
from test_search import Recorder, make_problem
from toy_scenarios import FOLLOW_SPEC, PLATOON_SPEC, RUNAWAY_LEAD_SPEC

ITERATIONS = 3
NEAR, FAR, ONCOMING = 1, 2, 7  # PLATOON_SPEC's agent ids


def joint_rows(log):
    return [row for row in log if row.phase == "joint"]


@pytest.fixture(scope="module")
def platoon():
    problem, recorder, _ = make_problem(PLATOON_SPEC)
    heuristic = heuristic_search(problem, ITERATIONS)
    joint = joint_drops(problem, heuristic, ITERATIONS, max_agents=8)
    return problem, recorder, heuristic, joint


def test_the_platoon_needs_both_cars_hidden(platoon):
    """The scenario is what it claims: no single drop collides, every agent hidden does."""
    problem, _, heuristic, joint = platoon
    assert not heuristic.modes and not any(drop.adversarial for drop in heuristic.drops)
    assert joint.blind.adversarial and joint.blind.errors.fn.all()


def test_the_minimal_set_is_exactly_the_two_cars(platoon):
    _, _, _, joint = platoon
    assert sorted(joint.agents) == [NEAR, FAR]


def test_the_failure_mode_collides_and_drops_only_the_set_each_as_one_segment(platoon):
    problem, recorder, _, joint = platoon
    mode = joint.mode
    assert mode.adversarial and not mode.rollout.inconclusive
    assert not mode.errors.dx.any() and not mode.errors.dy.any() and not mode.errors.dyaw.any()
    ids = [problem.scenario.agent_id(j) for j in range(problem.scenario.agents.shape[1])]
    dropped = {ids[j] for j in np.flatnonzero(mode.errors.fn.any(axis=0))}
    assert dropped == {NEAR, FAR}
    for j in np.flatnonzero(mode.errors.fn.any(axis=0)):
        frames = np.flatnonzero(mode.errors.fn[:, j])
        assert np.array_equal(frames, np.arange(frames[0], frames[-1] + 1))
        assert frames.size < problem.scenario.num_frames  # the bisections narrowed every segment
    # it is the last colliding joint rollout, and it was rolled out as it stands
    last = max(i for i, (_, result) in enumerate(recorder.calls) if result.collided)
    assert recorder.calls[last][0].equals(mode.errors)


def test_the_joint_rollouts_stay_within_their_bound(platoon):
    """Beyond the heuristic's drops: the reduction within worst_case, the bisections within the 2 x
    iterations per agent that the single agents did not use."""
    problem, _, heuristic, joint = platoon
    num_agents = problem.scenario.agents.shape[1]
    rows = joint_rows(problem.log)
    narrowing = [row for row in rows if row.agent != -1]
    assert len(rows) - len(narrowing) <= worst_case(8, num_agents)
    assert len(narrowing) <= 2 * ITERATIONS * len(joint.agents)
    assert len(problem.log) == 1 + num_agents + len(rows)  # ground truth, drops, joint: nothing else ran
    # sets rolled out before are not rolled out again: the reduction rolls out {near, far} alone
    assert len(rows) - len(narrowing) == 2


def test_the_whole_search_finds_the_attack_within_the_default_budget():
    problem, _, _ = make_problem(PLATOON_SPEC)
    config = SearchConfig(heuristic_iterations=ITERATIONS, method="paper")
    result = run_search(problem, config)
    assert result.best is not None and result.best.adversarial and result.heuristic is result.joint.mode
    assert sorted(result.joint.agents) == [NEAR, FAR]
    assert {row.phase for row in problem.log} >= {"joint", "random", "refine"}
    num_agents = problem.scenario.agents.shape[1]
    assert len(problem.log) <= bound(config, num_agents, joint=True)
    assert bound(config, num_agents, joint=True) == bound(config, num_agents) + worst_case(8, num_agents)
    # the random search and refine act on the jointly dropped agents: the attack drops fewer frames
    assert result.best.errors.fn.sum() <= result.heuristic.errors.fn.sum()
    assert result.best.metric >= result.heuristic.metric


def test_a_cap_of_one_agent_keeps_the_colliding_set_it_reached():
    problem, _, _ = make_problem(PLATOON_SPEC)
    heuristic = heuristic_search(problem, ITERATIONS)
    joint = joint_drops(problem, heuristic, ITERATIONS, max_agents=1)
    assert {NEAR, FAR} <= set(joint.agents) and joint.mode.adversarial
    assert len(joint_rows(problem.log)) - sum(row.agent != -1 for row in joint_rows(problem.log)) \
        <= worst_case(1, problem.scenario.agents.shape[1])


def test_switched_off_nothing_runs():
    problem, _, _ = make_problem(PLATOON_SPEC)
    result = run_search(problem, SearchConfig(heuristic_iterations=ITERATIONS, joint_max_agents=0, approach_steps=0))
    assert result.best is None and result.joint is None and not joint_rows(problem.log)
    assert worst_case(0, 3) == 0


def test_a_blind_rollout_that_stays_clear_ends_the_joint_drops():
    """The lead drives away faster than the ego may: hiding everything is one rollout, and clear (the
    approach phase, which would follow, is off)."""
    problem, _, _ = make_problem(RUNAWAY_LEAD_SPEC)
    result = run_search(problem, SearchConfig(heuristic_iterations=ITERATIONS, approach_steps=0))
    assert result.best is None and result.joint.agents == () and result.joint.mode is None
    assert not result.joint.blind.adversarial and result.joint.blind.errors.fn.all()
    assert [row.phase for row in problem.log][-1] == "joint" and len(joint_rows(problem.log)) == 1


def _log(config):
    problem, recorder, _ = make_problem(FOLLOW_SPEC)
    result = run_search(problem, config)
    return result, [dataclasses.astuple(row) for row in problem.log], recorder.calls


@pytest.mark.parametrize("method", METHODS)
def test_with_an_influential_agent_the_joint_drops_run_nothing(method):
    """A single drop collides (the lead): the same rollouts, log and attack as with joint drops off."""
    config = SearchConfig(heuristic_iterations=ITERATIONS, random=dataclasses.replace(SearchConfig().random, steps=5),
                          method=method)
    with_joint, log, calls = _log(config)
    without, log_off, calls_off = _log(dataclasses.replace(config, joint_max_agents=0))
    assert with_joint.joint is None and not any(row[1] == "joint" for row in log)
    np.testing.assert_equal(log, log_off)  # NaN best_metric before the first collision compares equal
    assert all(a.equals(b) for (a, _), (b, _) in zip(calls, calls_off))
    assert with_joint.best.errors.equals(without.best.errors)
    num_agents = len(FOLLOW_SPEC["agents"])
    assert bound(config, num_agents) == 1 + num_agents * (1 + 2 * ITERATIONS) + 5 + 2 * config.refine_iterations


def test_worst_case_counts_each_kept_agent_s_bisection_and_set():
    assert worst_case(8, 1) == 0  # one agent: its drop is the blind rollout
    assert worst_case(8, 2) == 8 * (1 + 1)
    assert worst_case(8, 83) == 8 * (1 + 7)


def test_no_agent_no_joint_drops():
    spec = {**FOLLOW_SPEC, "name": "empty", "agents": []}
    scenario = build_scenario(spec)
    problem = AttackProblem(scenario, Recorder(scenario), "nds_t")
    heuristic = heuristic_search(problem, ITERATIONS)
    assert joint_drops(problem, heuristic, ITERATIONS, 8) is None and len(problem.log) == 1
