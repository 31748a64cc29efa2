"""Rollouts forked from snapshots (core.forks) against full rollouts from frame 0: bit for bit the same on
every bundled planner and every error kind, under replayed and reactive traffic, with the tracker left
out or the detections' velocities dropped; a plug-in planner without snapshot() forks from deep copies
once checked, and one whose deep copies differ is rolled out whole; the cache keeps to its memory."""

import logging
from dataclasses import replace

import numpy as np
import pytest
from toy_scenarios import FOLLOW_SPEC

from advperc_ros.backends.embedded import Stack
from advperc_ros.configs import core_configs
from advperc_ros.core.forks import DEEP_COPY, NATIVE, WHOLE, Forks, FrameState, PlannerSnapshots, Trunk, footprint
from advperc_ros.core.perception_errors import ERROR_KINDS, PerceptionErrors
from advperc_ros.core.perception_errors.registry import kind_named
from advperc_ros.core.planners.base import PlanningContext, SolveTimes, planner_stats
from advperc_ros.core.planners.idm import IDMPlanner
from advperc_ros.core.planners.obp import OBPPlanner
from advperc_ros.core.planners.obp.planner import MEMO_ENV, MEMO_SOLVES, SolveMemo, solve_key
from advperc_ros.core.planners.obp.prediction import Obstacle
from advperc_ros.core.rollout import RolloutConfig, identical, rollout
from advperc_ros.core.scenario import EgoState
from advperc_ros.core.scenario_spec import build_scenario
from advperc_ros.core.tracker import NoTracker, Tracker
from advperc_ros.core.traffic import IDMParameters
from advperc_ros.params.strict_yaml import load_params

# the lead 12 m ahead, a follower 14 m behind (who brakes for the ego under reactive traffic), an oncoming car
SPEC = {**FOLLOW_SPEC, "duration": 4.0, "agents": [
    *FOLLOW_SPEC["agents"], {"id": 9, "lane": "east", "start_s": 86.0, "speed": 9.0, "size": [4.5, 1.8, 1.5]}]}
SCENARIO = build_scenario(SPEC)
T, N = SCENARIO.agents.shape
CONTEXT = PlanningContext(route=SCENARIO.route, lanes=SCENARIO.lanes, dt=SCENARIO.dt, ego_length=4.6, ego_width=1.9)
GHOSTS = 2


def planner(name: str):
    return IDMPlanner(CONTEXT, target_speed=14.0) if name == "idm" else OBPPlanner(CONTEXT, target_speed=10.0)


def kind_errors(kind: str, start: int, rng: np.random.Generator, base: PerceptionErrors | None = None) -> PerceptionErrors:
    """`base` (no errors if None) with frames `start`.. of `kind`'s arrays drawn anew: errors that first
    change the detections at `start` (or later, where a draw changes nothing there)."""
    e = (base or PerceptionErrors.none(T, N, ERROR_KINDS, GHOSTS)).copy()
    for name in kind_named(kind).array_names:
        array = e.arrays()[name]
        part = array[start:]
        if array.dtype == bool:
            part[:] = rng.random(part.shape) < 0.5
        elif name == "latency":
            part[:] = rng.integers(1, 4, part.shape)
        elif name.endswith("_scale"):
            part[:] = rng.uniform(0.6, 1.8, part.shape)
        elif name in ("ghost_x", "ghost_y"):  # in the ego's lane 12 m ahead of it, roughly
            ahead = 12.0 + 0.8 * np.arange(start, T)[:, None] if name == "ghost_x" else -1.75
            part[:] = ahead + rng.normal(0.0, 1.0, part.shape)
        else:
            part[:] = rng.normal(0.0, 1.0, part.shape)
    return e


def test_every_error_kind_names_its_arrays():
    """kind_errors draws every array of every kind (a kind added later must be drawn here too)."""
    rng = np.random.default_rng(0)
    for kind in ERROR_KINDS:
        e = kind_errors(kind, 0, rng)
        changed = [name for name, array in e.arrays().items()
                   if not np.array_equal(array, PerceptionErrors.none(T, N, ERROR_KINDS, GHOSTS).arrays()[name])]
        assert changed, kind


def assert_forks_equal_full(name: str, config: RolloutConfig, tracker_factory=Tracker, rollouts: int = 2) -> Forks:
    """Per error kind, `rollouts` tensors that share longer and longer beginnings, each forked and full."""
    rng = np.random.default_rng(len(name))
    forked_planner, full_planner = planner(name), planner(name)
    forked_tracker, full_tracker = tracker_factory(), tracker_factory()
    forks = Forks(64 << 20, PlannerSnapshots.of(forked_planner))
    assert forks.planner.how == NATIVE
    truth = PerceptionErrors.none(T, N, ERROR_KINDS, GHOSTS)
    tensors = [truth]
    for kind in ERROR_KINDS:
        e = kind_errors(kind, int(rng.integers(5, T // 2)), rng)
        tensors.append(e)
        for _ in range(rollouts - 1):  # a child of the last: the same up to a later frame
            e = kind_errors(kind, int(rng.integers(T // 2, T - 3)), rng, e)
            tensors.append(e)
    started_late = 0
    for errors in tensors:
        forked = rollout(SCENARIO, errors, forked_tracker, forked_planner, config, forks=forks)
        full = rollout(SCENARIO, errors, full_tracker, full_planner, config)
        assert identical(forked, full), (name, forks.last_fork)
        if (stats := planner_stats(forked_planner)) is not None:  # the frames it skipped hold their solve times
            assert len(stats.solve_times) == len(planner_stats(full_planner).solve_times)  # type: ignore[union-attr]
        started_late += forks.last_fork is not None
    assert started_late >= len(tensors) // 2  # most of them forked: the comparison is of forks
    assert forks.frames_skipped > 0
    return forks


@pytest.mark.parametrize("name", ["idm", "obp"])
def test_forked_rollouts_equal_full_ones_for_every_planner_and_kind(name):
    assert_forks_equal_full(name, RolloutConfig(), rollouts=2 if name == "idm" else 1)


def test_obp_answers_a_call_it_solved_before_as_solving_it_again():
    """ObP's solve memo: with every error kind, rollouts of a planner that keeps its solves equal those of one that
    keeps none, to the bit (planner failures and the fallbacks that answered them included), though most of the
    calls were answered from the memo: a child tensor shares its parent's beginning, and hiding a car the
    planner has pruned changes its tracks but not its obstacles."""
    rng = np.random.default_rng(3)
    remembering, forgetting = planner("obp"), planner("obp")
    forgetting.memo = SolveMemo(0)
    tensors = [PerceptionErrors.none(T, N, ERROR_KINDS, GHOSTS)]
    passed = tensors[0].copy()
    passed.fn[T // 2 :, 2] = True  # the oncoming car, hidden once it has passed the ego
    tensors.append(passed)
    for kind in ERROR_KINDS:
        e = kind_errors(kind, int(rng.integers(5, T // 2)), rng)
        tensors += [e, kind_errors(kind, int(rng.integers(T // 2, T - 3)), rng, e)]
    for errors in tensors:
        kept = rollout(SCENARIO, errors, Tracker(), remembering, RolloutConfig())
        solved = rollout(SCENARIO, errors, Tracker(), forgetting, RolloutConfig())
        assert identical(kept, solved)
        assert remembering.fallbacks == forgetting.fallbacks
    assert forgetting.memo.hits == 0
    assert remembering.memo.hits > remembering.memo.misses  # the comparison is of remembered answers


def test_the_solve_memo_is_on_unless_the_environment_turns_it_off(monkeypatch):
    """ADVPERC_OBP_MEMO=0 keeps no solves (fork_bench's baseline: every planning call solved); a value that is
    neither 0 nor 1 is refused, naming the variable, rather than taken for one of them."""
    assert planner("obp").memo.entries == MEMO_SOLVES
    monkeypatch.setenv(MEMO_ENV, "0")
    off = planner("obp")
    off.plan(0.0, EgoState(0.0, -1.75, 0.0, 5.0), {key: np.zeros(0) for key in
                                                  ("ids", "x", "y", "yaw", "vx", "vy", "length", "width", "height")})
    assert off.memo.entries == 0 and off.memo.misses == 1 and not off.memo.get(b"anything")
    monkeypatch.setenv(MEMO_ENV, "off")
    with pytest.raises(ValueError, match=r"ADVPERC_OBP_MEMO='off': 0 .* or 1"):
        planner("obp")


def _obstacle(**changes) -> Obstacle:
    fields = dict(id=7, cx=np.arange(4.0), cy=np.zeros(4), yaw=0.1, a=5.0, b=2.5, s=np.arange(4.0), d=np.zeros(4),
                  speed_along=3.0)
    return Obstacle(**{**fields, **changes})


@pytest.mark.parametrize("change", ["t", "ego", "controls", "no controls", "id", "cx", "cy", "yaw", "a", "b", "s", "d",
                                    "speed_along", "order", "one more"])
def test_a_solve_is_remembered_by_everything_both_stages_read(change):
    """A call differing from a remembered one in anything stage 1 or stage 2 reads has another key: the plan
    time, the ego's state, the previous controls, each field of each obstacle, and the obstacles' order."""
    ego, controls = EgoState(1.0, 2.0, 0.3, 4.0), np.array([[0.5, 0.2], [0.01, 0.0]])
    obstacles = [_obstacle(), _obstacle(id=8, cx=np.arange(4.0) + 10.0)]
    base = solve_key(0.5, ego, obstacles, controls)
    assert solve_key(0.5, EgoState(1.0, 2.0, 0.3, 4.0), [_obstacle(), _obstacle(id=8, cx=np.arange(4.0) + 10.0)],
                     controls.copy()) == base
    t, changed_controls, changed = 0.5, controls, list(obstacles)
    if change == "t":
        t = 0.6
    elif change == "ego":
        ego = EgoState(1.0, 2.0, 0.3, np.nextafter(4.0, 5.0))
    elif change == "controls":
        changed_controls = controls + np.array([[0.0, 1e-12], [0.0, 0.0]])
    elif change == "no controls":
        changed_controls = None
    elif change == "order":
        changed = obstacles[::-1]
    elif change == "one more":
        changed = [*obstacles, _obstacle(id=9)]
    else:
        value = getattr(obstacles[0], change)
        changed[0] = _obstacle(**{change: value + 1 if np.isscalar(value) else value + np.array([0, 0, 0, 1e-9])})
    assert solve_key(t, ego, changed, changed_controls) != base


@pytest.mark.parametrize("variant", ["reactive", "no_velocity", "no_tracker", "at_fault_no_stop"])
def test_forked_rollouts_equal_full_ones_however_the_rollout_is_run(variant):
    config = {"reactive": RolloutConfig(traffic=IDMParameters()), "no_velocity": RolloutConfig(detection_velocity=False),
              "no_tracker": RolloutConfig(), "at_fault_no_stop": RolloutConfig(at_fault_only=True,
                                                                                stop_at_collision=False)}[variant]
    assert_forks_equal_full("idm", config, NoTracker if variant == "no_tracker" else Tracker)


def test_reactive_forks_restore_agents_that_left_their_recording():
    """The follower brakes behind an ego that brakes for a ghost: forks after that frame restore its
    simulation, and the forked rollouts still equal full ones."""
    config = RolloutConfig(traffic=IDMParameters())
    ghost = PerceptionErrors.none(T, N, ERROR_KINDS, GHOSTS)
    ghost.ghost_on[5:, 0] = True  # a car standing 9 m ahead of the ego from frame 5: it brakes hard
    ghost.ghost_x[:, 0] = 9.0 + 0.8 * np.arange(T)
    ghost.ghost_y[:, 0] = -1.75
    forks = Forks(64 << 20, PlannerSnapshots.of(planner("idm")))
    stack_planner = planner("idm")
    first = rollout(SCENARIO, ghost, Tracker(), stack_planner, config, forks=forks)
    assert first.agents is not None and not np.array_equal(first.agents.x[:, 2], SCENARIO.agents.x[:, 2])
    later = ghost.copy()
    later.dx[T - 8 :, 0] = 1.5
    forked = rollout(SCENARIO, later, Tracker(), stack_planner, config, forks=forks)
    assert forks.last_fork is not None and forks.last_fork >= T - 8
    assert identical(forked, rollout(SCENARIO, later, Tracker(), planner("idm"), config))


def test_the_cache_keeps_to_its_memory_and_gives_up_leaves_first():
    tiny = Forks(0, PlannerSnapshots.of(planner("idm")))
    assert not tiny.enabled
    idm = planner("idm")
    one_rollout = Forks(1 << 30, PlannerSnapshots.of(idm))
    rollout(SCENARIO, PerceptionErrors.none(T, N), Tracker(), idm, forks=one_rollout)
    budget = one_rollout.used // 2
    forks = Forks(budget, PlannerSnapshots.of(idm))
    rollout(SCENARIO, PerceptionErrors.none(T, N), Tracker(), idm, forks=forks)
    assert 0 < forks.used <= budget
    frames = sorted(fork.state.frame for fork in forks._states.values())
    assert frames == list(range(len(frames)))  # the shallow ones kept, so every one left is reachable
    late = PerceptionErrors.none(T, N).with_drop(0, T - 5, T - 1)
    result = rollout(SCENARIO, late, Tracker(), idm, forks=forks)
    assert forks.last_fork == frames[-1]
    assert identical(result, rollout(SCENARIO, late, Tracker(), planner("idm")))
    assert forks.used <= budget


def test_footprint_counts_arrays_once():
    a = np.zeros(1000)
    assert footprint((a, a, a[10:])) < 2 * a.nbytes


def test_what_a_rollouts_snapshots_share_counts_once_with_the_shallowest():
    """A plan held over frames is in every snapshot of them: the cache counts it once, with the shallowest (the
    last of them to go), so giving up the deeper ones frees only what is theirs, and giving up all frees all."""
    held = np.zeros(100_000)  # 800 kB, in every snapshot
    own = [np.zeros(1000) for _ in range(10)]  # 8 kB, each snapshot's own
    snapshots = [(bytes([k]), FrameState(k, EgoState(0.0, 0.0, 0.0, 0.0), own[k], (held, k), None, 0, 0))
                 for k in range(10)]
    def trunk() -> Trunk:  # each rollout leaves its own
        return Trunk(np.zeros((10, 4)), np.zeros((10, 1)), np.zeros(10, dtype=bool), (), None)

    forks = Forks(1 << 30, PlannerSnapshots.of(planner("idm")))
    forks.keep(snapshots, trunk())
    assert held.nbytes + 10 * own[0].nbytes < forks.used < 1.2 * held.nbytes + 10 * own[0].nbytes + footprint(trunk())
    assert forks._sizes[bytes([0])] > held.nbytes > forks._sizes[bytes([9])]
    forks.memory = forks._sizes[bytes([0])] + 2 * footprint(trunk()) + 4096  # the shallowest and a small one
    forks.keep([(b"other", FrameState(0, EgoState(0.0, 0.0, 0.0, 0.0), None, None, None, 0, 0))], trunk())
    assert bytes([0]) in forks._states and bytes([9]) not in forks._states
    forks.memory = 0
    forks.keep([(b"last", FrameState(0, EgoState(0.0, 0.0, 0.0, 0.0), None, None, None, 0, 0))], trunk())
    assert forks.used == 0 and not forks._states


def test_a_mark_of_the_solve_times_stays_as_it_was():
    """Planners snapshot their solve times as a mark (the shared list and its length) in constant time: times
    added after the mark, or to a log made from it, leave it as it was."""
    times = SolveTimes()
    times.add(1.0)
    times.add(2.0)
    mark = times.mark()
    times.add(3.0)
    again = SolveTimes.at(mark)
    again.add(9.0)
    assert SolveTimes.at(mark).as_tuple() == (1.0, 2.0)
    assert times.as_tuple() == (1.0, 2.0, 3.0) and again.as_tuple() == (1.0, 2.0, 9.0) and len(again) == 3


def test_an_obp_snapshot_does_not_grow_with_its_frame():
    """Snapshots are taken every frame a rollout drives: one that copied every solve time so far would make a
    rollout's snapshots quadratic in its frames (and sizing them walk every time)."""
    obp = planner("obp")
    forks = Forks(1 << 30, PlannerSnapshots.of(obp))
    rollout(SCENARIO, PerceptionErrors.none(T, N), Tracker(), obp, forks=forks)
    sizes = [forks._sizes[key] for key, _ in sorted(forks._states.items(), key=lambda item: item[1].state.frame)]
    assert len(sizes) == T and max(sizes[1:]) - min(sizes[1:]) < 4 * T  # the times copied each frame: 8 bytes a frame


class Delegating:
    """A plug-in without snapshot(): an IDM planner inside does the planning (no attributes of its own)."""

    __slots__ = ()

    def __init__(self, context, **params):
        self.inner = IDMPlanner(context, **params)

    def reset(self):
        self.inner.reset()

    def plan(self, t, ego, tracks):
        return self.inner.plan(t, ego, tracks)


class Wrapped(Delegating):
    """A plug-in without snapshot(): its state (the IDM planner inside) in its attributes."""


CALLS = [0]


class HiddenState(Wrapped):
    """A plug-in whose state is outside its attributes (a module global): deep copies cannot restore it."""

    def reset(self):
        super().reset()
        CALLS[0] = 0

    def plan(self, t, ego, tracks):
        CALLS[0] += 1
        plan = super().plan(t, ego, tracks)
        return replace(plan, x=plan.x + 0.01 * CALLS[0])  # drifts with the calls since the reset


class NoAttributes(Delegating):
    """A plug-in with slots only: nothing to deep-copy."""

    __slots__ = ("inner",)


class RestoreFails(IDMPlanner):
    def restore(self, state):
        raise RuntimeError("cannot go back")


def test_how_a_planner_is_kept():
    assert PlannerSnapshots.of(planner("idm")).how == NATIVE
    assert PlannerSnapshots.of(Wrapped(CONTEXT)).how == DEEP_COPY
    assert PlannerSnapshots.of(NoAttributes(CONTEXT)).how == WHOLE


def stack_search(bundled_params, planner_name: str, fork_memory: int):
    """The errors of a short guided search of the bundled lane-following scenario with a plug-in planner, through
    an embedded Stack, and the rollouts' results, so two stacks can be compared."""
    _, scenario, path = bundled_params
    params = load_params(path).with_values(planner=planner_name, fork_memory=fork_memory,
                                           planner_params={"target_speed": 10.0})
    stack = Stack(scenario, core_configs(params))
    t, n = scenario.agents.shape
    rng = np.random.default_rng(1)
    tensors = [PerceptionErrors.none(t, n)]
    for agent in range(min(n, 3)):  # a drop, and a child of it that drops another car from later on
        start = int(rng.integers(10, 40))
        tensors.append(PerceptionErrors.none(t, n).with_drop(agent, start, t - 1))
        tensors.append(tensors[-1].with_drop((agent + 1) % n, start + 10, t - 1))
    return stack, [stack.rollout(e) for e in tensors]


@pytest.mark.parametrize("plugin, forks", [("test_forks:Wrapped", True), ("test_forks:HiddenState", False),
                                           ("test_forks:NoAttributes", False),
                                           ("test_forks:RestoreFails", False)])
def test_a_plugin_planner_gives_the_same_rollouts_forked_or_not(bundled_lane_following, caplog, plugin, forks):
    with caplog.at_level(logging.INFO, logger="advperc_ros.backends.embedded"):
        stack, results = stack_search(bundled_lane_following, plugin, 256)
    _, whole = stack_search(bundled_lane_following, plugin, 0)
    assert all(identical(a, b) for a, b in zip(results, whole))
    said = [record.getMessage() for record in caplog.records]
    assert len(said) == 1, said  # once, which
    if forks:
        assert "rollouts fork from deep copies" in said[0] and stack.forks.frames_skipped > 0
    else:
        assert "every rollout runs from frame 0" in said[0] and not stack.forks.enabled


@pytest.fixture(scope="module")
def bundled_lane_following():
    from conftest import _bundled
    return _bundled("idm_lane_following")
