"""Phantom obstacles (core/search/phantom.py): with ghosts on, a ghost standing just ahead of the ego
is tried at starts spread over the ground truth, and one that makes the ego collide is a failure mode
the search moves from; with the paper's kinds nothing of it runs."""

import dataclasses

import numpy as np

from advperc_ros.core.perception_errors import ERROR_KINDS, PAPER_KINDS, ErrorSpace
from advperc_ros.core.search import phantom
from advperc_ros.core.search.config import SearchConfig, bound
from advperc_ros.core.search.pipeline import run_search
from advperc_ros.core.search.problem import Phase
from test_approach import LANE_Y, swerve_problem

EVERY_KIND = ErrorSpace(kinds=ERROR_KINDS)


def test_each_probe_is_one_standing_ghost_ahead_of_the_ego_on_its_own_path():
    problem = swerve_problem()
    truth = problem.evaluate(EVERY_KIND.blank(*problem.scenario.agents.shape), Phase.GROUND_TRUTH)
    ego, dt = truth.rollout.ego, problem.scenario.dt
    lead, span = round(phantom.PROBE_LEAD / dt), round(phantom.PROBE_SPAN / dt)
    probes = phantom.probes(truth, problem.scenario.agents.shape, dt, EVERY_KIND)
    assert len(probes) == phantom.PROBES == phantom.worst_case(EVERY_KIND)
    starts = [int(np.flatnonzero(p.ghost_on[:, 0])[0]) for p in probes]
    assert starts[0] == 0 and starts[-1] == len(ego) - 1 - lead and starts == sorted(set(starts))
    for start, p in zip(starts, probes):
        on = np.flatnonzero(p.ghost_on[:, 0])
        assert on.tolist() == list(range(start, min(start + span, p.shape[0])))
        assert not p.ghost_on[:, 1:].any() and not p.attacked().any()  # a ghost and nothing else
        x, y, yaw, _ = ego[start + lead]
        assert np.all(p.ghost_x[on, 0] == x) and np.all(p.ghost_y[on, 0] == y) and np.all(p.ghost_yaw[on, 0] == yaw)
        assert not p.ghost_vx.any() and not p.ghost_vy.any()  # it stands
        assert abs(y - LANE_Y) < 0.5 and x > ego[start, 0]  # in the ego's lane, ahead of it
    assert phantom.probes(truth, problem.scenario.agents.shape, dt, ErrorSpace()) == []
    assert phantom.worst_case(ErrorSpace()) == 0


def test_a_phantom_that_collides_is_a_failure_mode_where_no_drop_is():
    """The swerve scenario: no drop collides, but a car seen ahead in its lane makes the ego change
    lanes into the car beside it. With ghosts on, a phantom obstacle finds that at once (no joint
    drops, no approach phase), and the search moves on from it."""
    config = SearchConfig(method="guided", errors=EVERY_KIND, budget=40,
                          guided=dataclasses.replace(SearchConfig().guided, candidates=50))
    problem = swerve_problem()
    result = run_search(problem, config)
    phases = [row.phase for row in problem.log]
    num_agents = problem.scenario.agents.shape[1]
    assert phases[: 1 + num_agents] == [Phase.GROUND_TRUTH] + [Phase.HEURISTIC_DROP] * num_agents
    assert not any(row.collided for row in problem.log[: 1 + num_agents])
    assert phases[1 + num_agents : 1 + num_agents + phantom.PROBES] == [Phase.PHANTOM] * phantom.PROBES
    assert Phase.JOINT not in phases and Phase.APPROACH not in phases
    heuristic = result.heuristic
    assert heuristic is not None and heuristic.adversarial
    assert heuristic.errors.ghost_on.any() and not heuristic.errors.attacked().any()
    assert result.best is not None and result.best.metric >= heuristic.metric > 0.9  # one ghost costs little
    assert len(problem.log) <= 40


def test_the_paper_s_kinds_run_no_phantom_and_keep_the_paper_s_bound():
    problem = swerve_problem()
    config = SearchConfig(method="guided", budget=0, approach_steps=4, approach_patience=2)
    run_search(problem, config)
    assert all(row.phase != Phase.PHANTOM for row in problem.log)
    assert config.errors.kinds == PAPER_KINDS
    with_ghosts = dataclasses.replace(config, errors=EVERY_KIND)
    assert bound(with_ghosts, 3) == bound(config, 3) + phantom.PROBES
