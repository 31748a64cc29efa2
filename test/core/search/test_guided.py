"""The guided search and rollout budgets (README "Search"): budget kept and spent, the same attack
on 1 and 2 workers, resumable mid-batch, and the paper's method unchanged."""

import json
from dataclasses import replace

import numpy as np
import pytest

from advperc_ros.application import attack_to_folder, run_attack
from advperc_ros.configs import core_configs
from advperc_ros.backends.embedded import Stack
from advperc_ros.core.perception_errors import PerceptionErrors
from advperc_ros.core.metrics.nds import DIST_THRESHOLDS
from advperc_ros.core.rollout import RolloutResult
from advperc_ros.core.search import guided
from advperc_ros.core.search.guided import (MOVES, PRIOR_WEIGHT, _features, fit_still_fails, merge, next_radius,
                                            pick_batch, push, shown, trust_region, wrongness)
from advperc_ros.core.search.pipeline import run_search
from advperc_ros.core.search.problem import AttackProblem, Phase
from advperc_ros.exceptions import Interrupted, ParamsError
from advperc_ros.params import load_params
from advperc_ros.ros.bag import read_scenario
from conftest import REPO

# idm_lane_following: ground truth, 5 drops (one batch under the guided method), 6 bisections
HEURISTIC_ROLLOUTS = 12


@pytest.fixture(scope="module")
def lane_following():
    return read_scenario(REPO / "bags" / "idm_lane_following"), load_params(REPO / "config" / "idm_lane_following.yaml")


def _guided(params, budget, **values):
    return params.with_values(**{"search.method": "guided", "search.budget": budget, **values})


def _trace(outcome):
    return [(row.phase, row.metric, row.min_signed_distance, row.collided) for row in outcome.log]


@pytest.fixture(scope="module")
def guided_runs(lane_following):
    """A guided search of budget 18 on 1 worker and on 2."""
    scenario, params = lane_following
    return {workers: run_attack(scenario, _guided(params, 18, workers=workers), progress=False) for workers in (1, 2)}


def test_guided_spends_exactly_its_budget(guided_runs):
    """6 rollouts after the heuristic: too few to give the refine phase its share (2 x 4) after
    rounds have had as many, so all 6 are rounds."""
    outcome = guided_runs[1]
    assert len(outcome.log) == 18
    assert [row.phase for row in outcome.log[HEURISTIC_ROLLOUTS:]] == [Phase.GUIDED] * 6


def test_refine_runs_once_when_the_rollouts_left_are_its_share(lane_following):
    """Budget 30 under NDS (drops stay): rounds until 8 rollouts are left (10 rounds by then), one
    refine bisection of the dropped run (4 rollouts), then rounds again."""
    scenario, params = lane_following
    outcome = run_attack(scenario, _guided(params, 30, objective="nds"), progress=False)
    phases = [row.phase for row in outcome.log[HEURISTIC_ROLLOUTS:]]
    assert phases == [Phase.GUIDED] * 10 + [Phase.REFINE] * 4 + [Phase.GUIDED] * 4


def test_guided_improves_on_the_heuristic(guided_runs):
    outcome = guided_runs[1]
    assert outcome.best.metric > outcome.heuristic_best.metric


def test_two_workers_give_the_same_attack_bit_for_bit(guided_runs):
    one, two = guided_runs[1], guided_runs[2]
    assert _trace(one) == _trace(two)
    assert one.best.errors.equals(two.best.errors)


@pytest.mark.parametrize("method, budget", [("paper", 6), ("paper", 13), ("guided", 9)])
def test_a_budget_ends_the_search_there(lane_following, method, budget):
    """Mid-heuristic (paper 6 and guided 9, mid-bisection) or in the paper's random search (13): the
    best attack so far reported; never past the budget."""
    scenario, params = lane_following
    outcome = run_attack(scenario, _guided(params, budget).with_values(**{"search.method": method}), progress=False)
    assert len(outcome.log) == budget
    assert outcome.best is not None and outcome.best.rollout.collided


@pytest.mark.parametrize("method", ["paper", "guided"])
def test_a_budget_below_one_drop_per_agent_is_refused_before_any_rollout(lane_following, method):
    """Below the ground truth and one drop of each of the 5 agents no search can try every agent (the
    guided method's first batch, all six, did not fit at all and ended in a StopIteration)."""
    scenario, params = lane_following
    with pytest.raises(ParamsError, match="'search.budget' is 5, below the 6 rollouts"):
        run_attack(scenario, _guided(params, 5).with_values(**{"search.method": method}), progress=False)


def test_the_default_search_is_guided_with_the_paper_s_budget_after_the_failure_mode(lane_following, capsys):
    """Default params (README Table 1's guided row: NDS-t 0.943 in 60 rollouts): the heuristic's 12
    rollouts, then the paper's bound's share for 40 random steps and 2 x 4 refine bisections, all
    spent (not the whole bound 1 + 7 x 5 + 48 = 84, which counts bisections of agents whose drop
    did not collide); the progress bar ends at the count, having shown it since the rounds began."""
    scenario, params = lane_following
    outcome = run_attack(scenario, params, progress=True)
    assert {row.phase for row in outcome.log[HEURISTIC_ROLLOUTS:]} == {Phase.GUIDED}
    assert len(outcome.log) == HEURISTIC_ROLLOUTS + 40 + 8
    assert round(outcome.best.scores.nds_t, 3) == 0.943
    lines = capsys.readouterr().err.replace("\r", "\n").splitlines()
    totals = {line.split("/")[1].split(" ")[0] for line in lines if "(guided search)" in line and "/" in line}
    assert totals == {str(HEURISTIC_ROLLOUTS + 48)}, totals


def test_paper_method_unchanged(lane_following):
    """README Table 1: idm_lane_following, nds_t, seed 0, paper-sized search: NDS-t 0.933 in 33 rollouts."""
    scenario, params = lane_following
    outcome = run_attack(scenario, params.with_values(**{"search.method": "paper"}), progress=False)
    assert len(outcome.log) == 33
    assert round(outcome.best.scores.nds_t, 3) == 0.933


def test_guided_attack_resumes_mid_batch_to_the_same_report(lane_following, tmp_path, monkeypatch):
    _, params = lane_following
    params = _guided(params, 19).with_values(bag=str(REPO / "bags" / "idm_lane_following"))
    whole, _ = attack_to_folder(params, tmp_path / "whole")
    calls, rollout = [0], Stack.rollout

    def killed_at_the_sixteenth(self, errors, record=False):  # the second rollout of the first guided batch
        calls[0] += 1
        if calls[0] == HEURISTIC_ROLLOUTS + 2:
            raise KeyboardInterrupt
        return rollout(self, errors, record)

    monkeypatch.setattr(Stack, "rollout", killed_at_the_sixteenth)
    with pytest.raises(Interrupted):
        attack_to_folder(params, tmp_path / "cut")
    monkeypatch.setattr(Stack, "rollout", rollout)
    attack_to_folder(params, tmp_path / "cut", resume=True)
    reports = [json.loads((folder / "report.json").read_text()) for folder in (whole, tmp_path / "cut")]
    for report in reports:
        report.pop("wall_time_s")
    assert reports[0] == reports[1]


def test_pick_batch_pairs_a_bold_candidate_with_a_safe_one():
    gain = np.array([1.0, 0.9, 0.3])
    chance = np.array([0.5, 0.5, 0.99])
    # first the largest expected gain alone (0.5 > 0.45 > 0.297); then what pays where it fails:
    # 0.5 + 0.5 * 0.5 * 0.9 = 0.725 for the second bold one against 0.5 + 0.5 * 0.99 * 0.3 = 0.6485
    assert pick_batch(gain, chance, 2) == [0, 1]
    # a second bold one that rarely collides: 0.5 + 0.5 * 0.1 * 0.9 = 0.545, the safe one is worth more
    assert pick_batch(gain, np.array([0.5, 0.1, 0.99]), 2) == [0, 2]


def _dropped_run(frames=20, agents=2, first=5, last=14, slot=1):
    return PerceptionErrors.none(frames, agents).with_drop(slot, first, last)


@pytest.mark.parametrize("axis, along, beside", [(0, 1, 0), (1, -1, 0), (2, 0, 1), (3, 0, -1)])
def test_a_push_displaces_a_run_along_its_axis_just_inside_a_match_threshold(axis, along, beside):
    """Ahead, behind, left and right of the car's own heading, by 0.95 x one of the 0.5/1/2/4 m
    thresholds: detected again (no drop), on the run's frames only."""
    errors = _dropped_run()
    yaw = np.tile(np.linspace(-3.0, 3.0, 20)[:, None], (1, 2))
    seen = set()
    for seed in range(40):
        out = push(errors, 20, np.random.default_rng(seed), yaw, axis)
        moved = (out.dx != 0) | (out.dy != 0)
        assert not out.fn[moved].any() and moved[:, 0].sum() == 0
        frames = np.flatnonzero(moved[:, 1])
        assert 5 <= frames[0] and frames[-1] <= 14
        heading = np.column_stack([np.cos(yaw[frames, 1]), np.sin(yaw[frames, 1])])
        left = np.column_stack([-heading[:, 1], heading[:, 0]])
        offset = np.column_stack([out.dx[frames, 1], out.dy[frames, 1]])
        distance = np.hypot(offset[:, 0], offset[:, 1])
        assert np.allclose(distance, distance[0])
        assert np.allclose(np.sum(offset * heading, axis=1), along * distance[0])
        assert np.allclose(np.sum(offset * left, axis=1), beside * distance[0])
        seen.add(round(float(distance[0]), 6))
    assert seen == {round(0.95 * t, 6) for t in DIST_THRESHOLDS}


def test_a_merge_puts_a_siblings_change_on_the_best_attack():
    parent = _dropped_run()
    best = parent.copy()
    best.fn[5:8, 1] = False
    best.dx[5:8, 1] = 0.4  # the round's best: the run's first frames detected again, offset
    sibling = parent.copy()
    sibling.fn[12:15, 1] = False
    sibling.dy[12:15, 1] = -1.9  # another collision of the round: the last frames detected again
    merged = merge(best, sibling, parent)
    assert not merged.fn[5:8, 1].any() and not merged.fn[12:15, 1].any() and merged.fn[8:12, 1].all()
    assert np.all(merged.dx[5:8, 1] == 0.4) and np.all(merged.dy[12:15, 1] == -1.9)
    assert merge(best, parent.copy(), parent) is None  # a sibling that changed nothing adds nothing


def test_what_a_candidate_shows_drives_the_collision_model():
    """Falsity: how wrong the changed object-frames are shown; revealed: the share of the parent's
    wrongness taken back. Restoring 1 frame of a 10-frame drop reveals a tenth and shows the truth;
    a 3.8 m push of the whole run reveals 5 % and shows it 95 % wrong; a 0.475 m push reveals most."""
    parent = _dropped_run()  # frames 5..14 of slot 1 dropped
    before = wrongness(parent)
    one = parent.copy()
    one.fn[5, 1] = False
    assert shown(one, parent, before) == (0.0, pytest.approx(0.1))
    far, near = parent.copy(), parent.copy()
    for errors, metres in ((far, 3.8), (near, 0.475)):
        errors.fn[5:15, 1] = False
        errors.dy[5:15, 1] = metres
    assert shown(far, parent, before) == (pytest.approx(0.95), pytest.approx(0.05))
    assert shown(near, parent, before) == (pytest.approx(0.11875), pytest.approx(0.88125))
    assert shown(parent, far, wrongness(far))[1] < 0  # hiding a shown car again takes nothing back


def test_without_refine_iterations_every_rollout_after_the_heuristic_is_a_round(lane_following):
    scenario, params = lane_following
    outcome = run_attack(scenario, _guided(params, 16, **{"search.refine.iterations": 0}), progress=False)
    assert [row.phase for row in outcome.log[HEURISTIC_ROLLOUTS:]] == [Phase.GUIDED] * 4


def test_before_its_own_rollouts_the_model_prefers_a_moderate_step_and_they_outweigh_it():
    """With no rollouts the expected gain, gain x P(collides), peaks at a moderate step, not the
    boldest (the prior counts PRIOR_WEIGHT rollouts a row); once more bold steps than that have
    kept the collision, the model expects the next bold one to keep it too."""
    relative = np.linspace(0.0, 1.0, 101)
    seen = np.full((relative.size, 2), 0.5)
    moves = np.full(relative.size, MOVES.index("push_right"))

    def chance(w):
        return 1.0 / (1.0 + np.exp(-_features(moves, relative, seen) @ w))

    empty = fit_still_fails(np.zeros(0, dtype=int), np.zeros(0), np.zeros((0, 2)), np.zeros(0, dtype=bool))
    best_step = relative[np.argmax(relative * chance(empty))]
    assert 0.2 < best_step < 0.8
    assert chance(empty)[-1] < 0.2
    bold = int(3 * PRIOR_WEIGHT)
    w = fit_still_fails(np.full(bold, MOVES.index("push_right")), np.ones(bold), np.full((bold, 2), 0.5),
                        np.ones(bold, dtype=bool))
    assert chance(w)[-1] > 0.5


def test_the_trust_region_shrinks_after_a_lost_round_and_doubles_after_a_gain():
    shrunk = 0.08 / np.sqrt(2)
    assert next_radius(np.inf, improved=False, all_lost=True, boldest=0.08) == pytest.approx(shrunk)
    assert next_radius(0.04, improved=True, all_lost=False, boldest=0.03) == pytest.approx(0.08)
    assert next_radius(0.04, improved=False, all_lost=False, boldest=0.03) == 0.04  # a collision that did not gain
    assert next_radius(0.04, improved=False, all_lost=True, boldest=0.9) == pytest.approx(0.04 / np.sqrt(2))  # a bold first pick
    assert next_radius(np.inf, improved=True, all_lost=False, boldest=0.5) == np.inf


def test_one_gain_undoes_two_lost_rounds():
    """The radius holds where a third of the rounds gain (as an evolution strategy's success rule
    holds its step where a fifth do): halved after every loss it held only where half did."""
    radius = 0.04
    for _ in range(2):
        radius = next_radius(radius, improved=False, all_lost=True, boldest=1.0)
    assert next_radius(radius, improved=True, all_lost=False, boldest=1.0) == pytest.approx(0.04)


def _narrow_boundary_search(scenario, params, slack):
    """A guided search against a planner that collides only while car 0 stays shown nearly as wrong
    as its whole-track drop (wrongness summed over the scenario at least its frames - `slack`): a
    failure boundary close to the heuristic's attack, as obp_right_turn's. The real ground truth."""
    truth = Stack(scenario, core_configs(params)).rollout(PerceptionErrors.none(*scenario.agents.shape))
    frames = scenario.agents.shape[0]

    def rollout(errors):
        collides = wrongness(errors)[:, 0].sum() >= frames - slack
        distances = truth.distances - (truth.distances.min() + 0.5 if collides else 0.0)
        return RolloutResult(ego=truth.ego, distances=distances)

    problem = AttackProblem(scenario, rollout, params.objective)
    config = replace(core_configs(params).search, method="guided", budget=40)  # at 60 even unbounded steps gain here
    run_search(problem, config)
    return problem


def test_after_rounds_that_lose_every_collision_the_steps_shrink_until_one_keeps_it(lane_following, monkeypatch):
    """Against a failure boundary close to the heuristic's attack the guided search still gains, by
    shrinking its second candidate's steps; without a trust region it never leaves the heuristic's
    attack (as on obp_right_turn under nds, before it had one)."""
    scenario, params = lane_following
    problem = _narrow_boundary_search(scenario, params, slack=1.0)
    heuristic = max(row.metric for row in problem.log if row.collided and row.phase.heuristic)
    # measured: 0.400 against 0.364; 0.599 when halved after every lost round, which reaches the small
    # steps this sharp boundary needs in fewer rounds (but on obp_right_turn sank below what gains)
    assert problem.best.metric > heuristic + 0.02
    monkeypatch.setattr(guided, "RADIUS_SHRINK", np.inf)
    unbounded = _narrow_boundary_search(scenario, params, slack=1.0)
    assert unbounded.best.metric == heuristic


def test_a_batchs_second_candidate_comes_from_within_the_trust_region():
    gain = np.array([1.0, 0.9, 0.3, 0.1])
    chance = np.array([0.5, 0.5, 0.99, 0.99])
    assert pick_batch(gain, chance, 2) == [0, 1]  # unbounded: the second bold one pays more
    assert pick_batch(gain, chance, 2, within=gain <= 0.5) == [0, 2]  # the first stays the model's choice
    assert pick_batch(gain, chance, 3, within=gain <= 0.2) == [0, 3, 1]  # none left within: any


def test_the_trust_region_keeps_the_second_pick_between_the_noise_floor_and_the_radius():
    gain = np.array([0.0005, 0.002, 0.01, 0.04, 0.2])
    assert trust_region(gain, np.inf, []).all()  # unbounded at first
    assert trust_region(gain, 0.02, []).tolist() == [True, True, True, False, False]
    assert trust_region(gain, 0.0001, []).tolist() == [True, False, False, False, False]  # at least the smallest
    # colliding rollouts landed 0.001-0.003 from their scores: steps below that median are noise
    assert trust_region(gain, 0.02, [0.001, 0.002, 0.003]).tolist() == [False, True, True, False, False]
    # a radius shrunk below the floor: the smallest step above the floor, not any candidate (pick_batch's
    # rule for an empty region), which would leave the second pick as bold as the first from then on
    assert trust_region(gain, 0.001, [0.005]).tolist() == [False, False, True, False, False]
    assert trust_region(gain, 0.005, [0.003]).tolist() == [False, False, True, False, False]  # none between: the nearest
    assert trust_region(gain, np.inf, [0.5]).tolist() == [False, False, False, False, True]  # at most the largest
