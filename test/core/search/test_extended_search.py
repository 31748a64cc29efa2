"""The search over the error kinds beyond the paper's (`errors.kinds`): each move does what it names
within the params' bounds, the paper's kinds keep the paper's moves and draws, and a guided attack
with every kind on is the same attack on one worker and on two, reports the kinds it uses and what
each costs, and replays from its npz."""

import json

import numpy as np
import pytest

from advperc_ros.application import attack_to_folder
from advperc_ros.cli import main
from advperc_ros.core.perception_errors import ERROR_KINDS, PAPER_KINDS, ErrorSpace, MoveContext, PerceptionErrors
from advperc_ros.core.perception_errors.kinds import flip, ghost, latency, size, velocity
from advperc_ros.core.search.guided import MOVES, candidate, moves_of
from advperc_ros.core.search.config import GuidedConfig
from advperc_ros.exceptions import ParamsError
from advperc_ros.params import load_params
from advperc_ros.results.folder import load_errors
from advperc_ros.ros.bag import read_scenario
from conftest import REPO

SPACE = ErrorSpace(kinds=ERROR_KINDS, max_speed_error=3.0, min_scale=0.7, max_scale=1.6, max_latency=4, ghosts=2)


@pytest.fixture(scope="module")
def lane_following():
    return read_scenario(REPO / "bags" / "idm_lane_following"), load_params(REPO / "config" / "idm_lane_following.yaml")


@pytest.fixture(scope="module")
def context(lane_following):
    scenario = lane_following[0]
    frames = scenario.num_frames
    ego = np.column_stack([np.linspace(0.0, 100.0, frames), np.zeros(frames), np.zeros(frames), np.full(frames, 10.0)])
    return MoveContext(scenario.agents, ego, SPACE, scenario.dt)


def test_the_paper_s_kinds_keep_the_paper_s_moves_and_every_kind_adds_its_own():
    assert moves_of(PAPER_KINDS) == MOVES
    every = moves_of(ERROR_KINDS)
    assert every[: len(MOVES) - 1] == MOVES[:-1] and every[-1] == "merge"
    assert every[len(MOVES) - 1 : -1] == ("faster_or_slower", "resized", "turned_around", "late", "ghost_ahead", "ghost_gone")
    assert moves_of((*PAPER_KINDS, "ghost")) == (*MOVES[:-1], "ghost_ahead", "ghost_gone", "merge")


def _changed(after: PerceptionErrors, before: PerceptionErrors) -> set[str]:
    before = before.with_kind(next(iter(set(after.kinds) - set(before.kinds)), "position"), SPACE.ghosts)
    return {name for name, array in after.arrays().items() if not np.array_equal(array, before.arrays()[name])}


def test_each_move_changes_its_kind_only_within_its_bounds(lane_following, context):
    scenario = lane_following[0]
    shape = scenario.agents.shape
    rng = np.random.default_rng(0)
    parent = PerceptionErrors.none(*shape)
    parent.fn[10:30, 1] = True  # an attacked run, as the heuristic leaves one
    for _ in range(30):
        c = velocity.faster_or_slower(parent, shape[0], rng, context)
        assert _changed(c, parent) <= {"dvx", "dvy", "fn"} and np.hypot(c.dvx, c.dvy).max() <= 3.0
        j = np.flatnonzero((c.dvx != 0).any(axis=0))
        assert j.size == 1 and not c.fn[c.dvx[:, j[0]] != 0, j[0]].any()  # a car shown, with its velocity wrong
        c = size.resized(parent, shape[0], rng, context)
        assert _changed(c, parent) <= {"length_scale", "width_scale", "fn"}
        assert 0.7 <= c.length_scale.min() and c.width_scale.max() <= 1.6
        c = flip.turned_around(parent, shape[0], rng, context)
        assert _changed(c, parent) <= {"flip", "fn"} and c.flip.any()
        c = latency.late(parent, shape[0], rng, context)
        assert _changed(c, parent) <= {"latency", "fn"} and 1 <= c.latency.max() <= 4
        c = ghost.ghost_ahead(parent, shape[0], rng, context)
        assert _changed(c, parent) <= {name for name in c.arrays() if name.startswith("ghost_")} and c.ghost_on.any()
        k, g = np.argwhere(c.ghost_on)[0]
        assert abs(c.ghost_y[k, g]) <= ghost.GHOST_ASIDE and c.ghost_x[k, g] >= context.ego[k, 0]  # in its way
        gone = ghost.ghost_gone(c, shape[0], rng, context)
        assert 0 < gone.ghost_on.sum() < c.ghost_on.sum() or c.ghost_on.sum() == 1 and not gone.ghost_on.any()
        PerceptionErrors.from_arrays(c.arrays())  # every candidate is a tensor a file or message may hold
    assert ghost.ghost_gone(parent, shape[0], rng, context) is None  # no ghost to take away


def test_a_candidate_of_an_extended_move_without_its_context_is_refused(lane_following):
    scenario = lane_following[0]
    errors = PerceptionErrors.none(*scenario.agents.shape)
    rng = np.random.default_rng(1)
    names = moves_of(ERROR_KINDS)
    with pytest.raises(ValueError, match="needs the move context"):
        for _ in range(200):
            candidate(errors, scenario.num_frames, rng, GuidedConfig(), scenario.agents.yaw, names)


def test_the_paper_s_search_refuses_the_extended_kinds(lane_following):
    params = lane_following[1]
    with pytest.raises(ParamsError, match="'errors.kinds' must be paper with search.method paper"):
        params.with_values(**{"search.method": "paper", "errors.kinds": "ghost"})
    with pytest.raises(ParamsError, match="unknown error kind 'ghosts'"):
        params.with_values(**{"errors.kinds": "ghosts"})


def test_every_kind_gives_one_attack_on_any_number_of_workers_and_says_what_each_costs(lane_following, tmp_path, capsys):
    scenario, params = lane_following
    params = params.with_values(**{"errors.kinds": "all", "search.budget": 30})
    reports = {}
    for workers in (1, 2):
        folder, report = attack_to_folder(params.with_values(workers=workers), tmp_path / f"w{workers}", progress=False)
        reports[workers] = (report, (folder / "search_log.csv").read_text(), load_errors(folder / "attack_errors.npz"))
    (one, log_one, errors_one), (two, log_two, errors_two) = reports[1], reports[2]
    assert log_one == log_two and errors_one.equals(errors_two) and one["nds_t"] == two["nds_t"]
    kinds = one["error_kinds"]
    assert kinds["enabled"] == list(ERROR_KINDS) and kinds["used"]
    assert set(kinds["used"]) <= set(errors_one.used_kinds(scenario.num_frames))  # what shows before the rollout ended
    assert set(kinds["cost"]) == set(kinds["used"]) and all(np.isfinite(cost) for cost in kinds["cost"].values())

    # the attack bag scored as the attack was: PEM LL under the calibrated model its kinds call for
    assert main(["score", str(REPO / "bags" / "idm_lane_following"), str(tmp_path / "w1" / "attack"), "--errors", "all"]) == 0
    scored = json.loads(capsys.readouterr().out)
    for key in ("nds", "nds_t"):
        assert scored[key] == pytest.approx(one[key], abs=1e-9), key
    assert scored["pem_ll"] == pytest.approx(one["pem_ll"], rel=1e-6)  # report.json holds 7 significant digits
    assert main(["score", str(REPO / "bags" / "idm_lane_following"), str(tmp_path / "w1" / "attack")]) == 0
    assert json.loads(capsys.readouterr().out)["pem_ll"] != pytest.approx(one["pem_ll"], abs=1e-3)  # the paper's model


def test_the_approach_phase_keeps_the_cars_it_bisects_to_with_all_their_kinds_and_every_ghost():
    from advperc_ros.core.search.approach import only

    errors = PerceptionErrors.none(6, 3, ERROR_KINDS, 2)
    errors.latency[:, 1] = 2
    errors.flip[:, 2] = True
    errors.dx[:, 2] = 1.0
    errors.ghost_on[2:4, 0] = True
    kept = only(errors, np.array([2]))
    assert not kept.latency.any() and kept.flip[:, 2].all() and (kept.dx[:, 2] == 1.0).all()
    assert np.array_equal(kept.ghost_on, errors.ghost_on) and kept.kinds == errors.kinds
