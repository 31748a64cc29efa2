"""The paper's rollout: agents replay ground truth (or, `RolloutConfig.traffic`, react to the ego).

Per frame k: score the collision rule for the ego at t_k, inject errors into the true boxes,
track, plan, and move the ego along the plan to t_{k+1}. By default agents never react to the ego;
under reactive traffic (core.traffic) frame k+1's agents follow from frame k's and the ego's state
there, before frame k+1 is judged and perceived. Either way a rollout is a pure function of
(scenario, errors, stack) and is deterministic.

A contact always ends a rollout that stops at collisions (a crash ends the drive); with
`at_fault_only` the verdict counts only the contacts that are the ego's fault (core.rules), so a
rollout that ends in the ego being rear-ended or hit while stopped is no violation.

The rules of a frame (`violates`, `after_plan`) and of what a rollout records (`recorded_frames`)
are written once here: `rollout` below runs them in one process, the graph's scenario player and
orchestrator (advperc_ros.nodes.scenario_player, advperc_ros.backends.graph) run them over DDS.
"""

import signal
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field

import numpy as np

from advperc_ros.core.boxes import BoxSequence
from advperc_ros.core.ego_motion import follow_plan
from advperc_ros.core.forks import ROOT, Forks, FrameState, Trunk, next_key
from advperc_ros.core.perception_errors import PerceptionErrors, inject, inject_frame
from advperc_ros.core.planners.base import Planner, ReportsStats, Trajectory, planner_stats
from advperc_ros.core.rules.contact import CollisionRule, excusable
from advperc_ros.core.scenario import EgoState, Scenario
from advperc_ros.core.tracker import ObjectTracker
from advperc_ros.core.traffic import IDMParameters, ReactiveTraffic, recorded_paths, simulate
from advperc_ros.exceptions import PlanError, PlanTimeout

STAGES = ("injector", "tracker", "planner", "rule")  # "planner" includes following the plan


@dataclass(frozen=True)
class RolloutConfig:
    """How a rollout is run and judged: the ego's footprint, whether a contact ends it, whether only
    contacts at the ego's fault count, and how long a plan call may take. Built from the params by
    `advperc_ros.configs`; its defaults are the schema's (a test checks), but for `plan_timeout`, None
    here so library and test rollouts set no alarm."""

    ego_length: float = 4.6  # m
    ego_width: float = 1.9  # m
    stop_at_collision: bool = True
    at_fault_only: bool = False  # the verdict counts only collisions that are the ego's fault
    plan_timeout: float | None = None  # s one plan call may take before the rollout is inconclusive
    # detections hand the tracker their velocity; False as from a detector whose message type has none
    # (vision_msgs/Detection3DArray), so that every backend tracks what the graph's tracker would receive
    detection_velocity: bool = True
    # reactive traffic's driver model (core.traffic): agents keep their recorded paths and brake for the ego;
    # None: they replay their recording (the paper's)
    traffic: IDMParameters | None = None


@dataclass
class RolloutResult:
    """What a rollout produced: the ego's trajectory and its signed distance to every agent per frame,
    which is all the search needs to judge it (`collided`) and score it; the tracks and plans only
    when recorded, for the attack bag. Every backend returns this, so the search cannot tell them apart."""

    ego: np.ndarray  # (K, 4): x, y, yaw, v at frames 0..K-1
    distances: np.ndarray  # (K, N): signed distance to each agent, +inf where absent
    inconclusive: str | None = None  # why the rollout has no verdict (planner failed), else None
    tracks: list[dict[str, np.ndarray]] | None = None  # per frame, when recorded
    plans: list[Trajectory] | None = None  # per frame, when recorded
    stage_times: dict[str, float] = field(default_factory=dict, repr=False)  # s per stage, for benchmarks
    # failed solves the planner answered with its fallback (its stats() of this rollout); None when
    # not known: a planner without stats(), or one in another process
    planner_failures: int | None = None
    # the frames whose plan the planner's fallback answered (its failures rose during that plan call),
    # for the rulebook's planner_failure rule; None when not known, as `planner_failures`
    fallback_frames: tuple[int, ...] | None = None
    # (K, N) where a contact would not be the ego's fault (`rules.contact.excusable`), when only at-fault ones
    # count (`judge`); None: every contact counts
    excusable: np.ndarray | None = None
    # the attacked rule's value when the search attacks a rule other than the contact rules
    # (`rules.verdict.AttackedRule`); None: the verdict is the contact rule's, from `counted`
    verdict: float | None = None
    # the true agents the rollout was judged on, frames 0..K-1 of them simulated, when traffic reacts
    # (`judge` sets it from the ego's states on every backend); None: the scenario's recording
    agents: BoxSequence | None = None

    @property
    def num_frames(self) -> int:
        return int(self.ego.shape[0])

    @property
    def ego_xy(self) -> np.ndarray:
        return self.ego[:, :2]

    @property
    def rule(self) -> np.ndarray:
        """Collision rule value per frame (minimum over agents)."""
        return self.distances.min(axis=1, initial=np.inf)

    @property
    def min_signed_distance(self) -> float:
        return float(self.rule.min(initial=np.inf))

    @property
    def margin(self) -> float:
        """How far the rollout stayed from a violation the verdict counts: the min signed distance
        over the contacts and near misses that would be the ego's fault (with `at_fault_only`, a car
        passing close behind the rear bumper, or the ego stopped, is no step towards a violation);
        below 0 exactly when a conclusive rollout collided. When the search attacks another rule, that
        rule's value (`verdict`), below 0 exactly when it is violated."""
        if self.verdict is not None:
            return self.verdict
        return float(self.counted.min(initial=np.inf))

    @property
    def counted(self) -> np.ndarray:
        """(K, N) the signed distances the verdict counts: +inf where a contact would be excused."""
        return self.distances if self.excusable is None else np.where(self.excusable, np.inf, self.distances)

    @property
    def excused(self) -> np.ndarray | None:
        """(K, N) the contacts that are not the ego's fault; None when every contact counts."""
        return None if self.excusable is None else (self.distances < 0.0) & self.excusable

    def closest_approach(self) -> tuple[int, int]:
        """(frame, agent slot) of the smallest signed distance: the collision, when there is one."""
        frame = int(np.argmin(self.rule))
        return frame, int(np.argmin(self.distances[frame]))

    @property
    def collided(self) -> bool:
        """The verdict: a conclusive rollout with a contact that counts (or, when the search attacks
        another rule, that violates it: `margin` below 0)."""
        if self.inconclusive is not None:
            return False
        return self.margin < 0.0


def judge(result: RolloutResult, scenario: Scenario, config: RolloutConfig) -> RolloutResult:
    """`result`, a rollout of `scenario`, with its true agents when traffic reacts (`true_agents`), and with the
    contacts that would not be the ego's fault excused when `config.at_fault_only`; from the ego states
    alone, so any backend's result is judged the same way."""
    if config.traffic is not None and result.agents is None:
        result.agents = simulate(recorded_paths(scenario.agents), config.traffic, scenario.dt, ego_size(config),
                                 result.ego)
    if config.at_fault_only:
        result.excusable = excusable(result.ego, config.ego_length, true_agents(result, scenario),
                                     reactive_dt=None if config.traffic is None else scenario.dt)
    return result


def identical(a: RolloutResult, b: RolloutResult) -> bool:
    """Whether two rollouts' results are the same bit for bit, timings aside: what a forked rollout owes a full one."""
    def same(x: np.ndarray | None, y: np.ndarray | None) -> bool:
        if x is None or y is None:
            return x is None and y is None
        return x.shape == y.shape and x.tobytes() == y.tobytes()

    agents = ("x", "y", "yaw", "vx", "vy", "valid")
    return (same(a.ego, b.ego) and same(a.distances, b.distances) and same(a.excusable, b.excusable)
            and a.inconclusive == b.inconclusive and a.planner_failures == b.planner_failures
            and a.fallback_frames == b.fallback_frames and (a.agents is None) == (b.agents is None)
            and (a.agents is None or all(same(getattr(a.agents, n), getattr(b.agents, n)) for n in agents)))


def true_agents(result: RolloutResult, scenario: Scenario) -> BoxSequence:
    """The true agents of a judged rollout of `scenario`: simulated when traffic reacted, else the recording."""
    return scenario.agents if result.agents is None else result.agents


def ego_size(config: RolloutConfig) -> tuple[float, float]:
    """(length, width) of the ego's box, as the traffic model sees it when it is an agent's leader."""
    return config.ego_length, config.ego_width


def violates(rule_value: float, stop_at_collision: bool) -> bool:
    """Whether the rollout ends at a frame whose rule value is `rule_value` (before planning it)."""
    return stop_at_collision and rule_value < 0.0


@dataclass(frozen=True)
class AfterPlan:
    """What follows frame k's plan: the ego at t_{k+1}, or the end of the rollout (the last frame
    was planned: done; or the plan cannot be followed: inconclusive, and why)."""

    ego: EgoState | None = None
    inconclusive: str | None = None

    @property
    def done(self) -> bool:
        return self.ego is None


def after_plan(plan: Trajectory, k: int, times: np.ndarray) -> AfterPlan:
    """Move the ego along frame k's plan to t_{k+1}; after the last frame there is nothing to follow."""
    if k + 1 == len(times):
        return AfterPlan()
    if not len(plan.t):
        return AfterPlan(inconclusive=f"frame {k}: the planner answered with an empty plan (it failed; see its log)")
    try:
        return AfterPlan(ego=follow_plan(plan, float(times[k + 1])))
    except PlanError as exc:
        return AfterPlan(inconclusive=f"frame {k}: {exc}")


def recorded_frames(frames: int, stopped_at_violation: bool, inconclusive: bool) -> tuple[int, int]:
    """(frames whose tracks, frames whose plan) a recorded rollout of `frames` frames keeps: no
    tracks or plan at a frame that ended it by a violation (it is not planned), no plan at the
    frame that made it inconclusive."""
    tracked = frames - 1 if stopped_at_violation else frames
    return tracked, tracked - (1 if inconclusive else 0)


@contextmanager
def plan_alarm(seconds: float | None) -> Iterator[Callable[[bool], object]]:
    """`arm(True)` before a plan call, `arm(False)` after: a call still running `seconds` later gets
    PlanTimeout raised inside it, so a hung plug-in makes its rollout inconclusive instead of
    stalling the search. SIGALRM, so only in a process's main thread (elsewhere, and without
    `seconds`, no limit), and only where Python runs: a call stuck inside C code is interrupted when
    it returns to Python."""
    if seconds is None or threading.current_thread() is not threading.main_thread():
        yield lambda on: None
        return

    def expire(signum: int, frame: object) -> None:
        raise PlanTimeout(f"no plan within {seconds:g} s")

    previous = signal.signal(signal.SIGALRM, expire)
    try:
        yield lambda on: signal.setitimer(signal.ITIMER_REAL, seconds if on else 0.0)
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0.0)
        signal.signal(signal.SIGALRM, previous)


def rollout(
    scenario: Scenario,
    errors: PerceptionErrors,
    tracker: ObjectTracker,
    planner: Planner,
    config: RolloutConfig = RolloutConfig(),
    record: bool = False,
    forks: Forks | None = None,
) -> RolloutResult:
    """One run of the stack on the scenario with `errors` injected, agents replaying ground truth and
    only the ego reacting (or, with `config.traffic`, the agents reacting to it too): per frame traffic
    step, rule check, injection, tracking, planning, ego motion.
    Deterministic in its inputs, so an attack found is reproducible and a checkpoint can answer a
    rollout it already ran. `record` keeps tracks and plans. With `forks` (and no `record`), it starts
    from the deepest snapshot of an earlier rollout whose detections it shares up to there (core.forks),
    and leaves its own snapshots: the same result, bit for bit."""
    clock = time.perf_counter
    stage_times = dict.fromkeys(STAGES, 0.0)
    started = clock()
    traffic = None if config.traffic is None else ReactiveTraffic(
        recorded_paths(scenario.agents), config.traffic, scenario.dt, ego_size(config))
    agents = scenario.agents if traffic is None else traffic.agents
    detections = inject(agents, errors).every_frame() if traffic is None else None

    def perceived(k: int, history: BoxSequence) -> dict[str, np.ndarray]:
        """What the tracker is handed at frame k, the agents of frames 0..k being `history`'s."""
        frame = detections[k] if detections is not None else inject_frame(history, k, errors)
        if not config.detection_velocity:
            frame = {**frame, "vx": np.zeros_like(frame["vx"]), "vy": np.zeros_like(frame["vy"])}
        return frame

    times = scenario.times
    num_frames = scenario.num_frames
    cache = forks if forks is not None and forks.enabled and not record else None  # None: no forking
    fork, key = (None, ROOT) if cache is None else cache.find(
        lambda k, at: perceived(k, agents if at is None or at.trunk.agents is None else at.trunk.agents), num_frames)
    stage_times["injector"] += clock() - started
    inconclusive = None
    ego = scenario.ego_start
    ego_states: list[tuple[float, float, float, float]] = []  # x, y, yaw, v at frames 0..k
    distances = np.full((num_frames, agents.shape[1]), np.inf)
    measured = np.zeros(num_frames, dtype=bool)  # frames measured during the drive: they could end it
    reports_stats = isinstance(planner, ReportsStats)
    failures_seen, fallback_frames = 0, []
    if cache is not None and fork is not None and fork.state.frame > 0:
        try:
            cache.planner.put(planner, fork.state.planner)
        except Exception as exc:  # a plug-in's restore() that fails: this and every later rollout from frame 0
            cache.disable(f"its restore() raised {type(exc).__name__}: {exc}")
            cache = fork = None
    first = 0 if fork is None else fork.state.frame
    if fork is not None and first > 0:
        state, trunk = fork.state, fork.trunk
        ego, failures_seen = state.ego, state.failures
        tracker.restore(state.tracker)
        if traffic is not None and trunk.agents is not None and state.traffic is not None:
            traffic.restore(state.traffic, trunk.agents, first)
        ego_states = [(x, y, yaw, v) for x, y, yaw, v in trunk.ego[:first].tolist()]
        measured[:first] = trunk.measured[:first]
        distances[:first][measured[:first]] = trunk.distances[:first][measured[:first]]
        fallback_frames = list(trunk.fallback_frames[: state.fallbacks])
    else:
        tracker.reset()
        try:
            planner.reset()
        except (Exception, SystemExit) as exc:  # a plug-in whose reset fails or exits plans nothing: no verdict
            inconclusive = f"frame 0: planner's reset() raised {type(exc).__name__}: {exc}"
            cache = None
    if forks is not None:
        forks.last_fork = first if first > 0 else None
    snapshots: list[tuple[bytes, FrameState]] = []
    rule = CollisionRule(agents, config.ego_length, config.ego_width)
    tracks_log: list[dict[str, np.ndarray]] = []
    plans_log: list[Trajectory] = []
    last = 0 if inconclusive is not None else num_frames - 1
    with plan_alarm(config.plan_timeout) as arm:
        for k in range(first, num_frames):
            t = float(times[k])
            if cache is not None and cache.wants(key):
                snapshots.append((key, FrameState(
                    k, ego, tracker.snapshot(), cache.planner.take(planner),
                    None if traffic is None else traffic.snapshot(), failures_seen, len(fallback_frames))))
            ego_states.append((ego.x, ego.y, ego.yaw, ego.v))
            if inconclusive is not None:  # reset() failed
                break
            started = clock()
            if traffic is not None and k > 0:  # frame k's agents answer the ego at frame k-1
                traffic.advance(k - 1, EgoState(*ego_states[k - 1]))
                rule.moved(k)
            frame = perceived(k, agents)
            if cache is not None:
                key = next_key(key, frame)
            stage_times["injector"] += clock() - started
            started = clock()
            ends = False
            if config.stop_at_collision and rule.may_touch(ego, k):  # else frame k cannot end the rollout
                distances[k], measured[k] = rule.distances(np.array(ego_states[k:]), [k])[0], True
                ends = violates(distances[k].min(initial=np.inf), config.stop_at_collision)
            stage_times["rule"] += clock() - started
            if ends:
                last = k
                break
            started = clock()
            tracks = tracker.step(t, frame)
            stage_times["tracker"] += clock() - started
            started = clock()
            try:
                arm(True)
                plan = planner.plan(t, ego, tracks)
                arm(False)
            except (Exception, SystemExit) as exc:  # a plug-in that crashes, hangs or exits gives no verdict, not a pass
                arm(False)
                inconclusive, last = f"frame {k}: planner raised {type(exc).__name__}: {exc}", k
            else:
                if reports_stats and (failures := planner.stats().failures) > failures_seen:  # type: ignore[attr-defined]
                    failures_seen = failures
                    fallback_frames.append(k)
                if not isinstance(plan, Trajectory):  # None, a list of poses...: a plan nobody can follow
                    inconclusive, last = f"frame {k}: planner returned {type(plan).__name__}, not a Trajectory", k
                else:
                    following = after_plan(plan, k, times)
                    if following.inconclusive is not None:
                        inconclusive, last = following.inconclusive, k
                    elif following.ego is not None:  # not done
                        ego = following.ego
            stage_times["planner"] += clock() - started
            if record:
                tracks_log.append(tracks)
                if inconclusive is None:
                    plans_log.append(plan)
            if inconclusive is not None:
                break
    started = clock()
    ego_path = np.array(ego_states, dtype=float).reshape(-1, 4)  # frames 0..last
    rest = np.flatnonzero(~measured[: last + 1])
    distances[rest] = rule.distances(ego_path[rest], rest)
    stage_times["rule"] += clock() - started
    stats = planner_stats(planner)
    if cache is not None:
        cache.count(first, last + 1)
        # copies: the result's arrays are the caller's; the agents are read only, as every result's
        cache.keep(snapshots, Trunk(ego_path.copy(), distances.copy(), measured, tuple(fallback_frames),
                                    None if traffic is None else traffic.agents))
    return judge(RolloutResult(
        ego=ego_path,
        distances=distances[: last + 1],
        inconclusive=inconclusive,
        tracks=tracks_log if record else None,
        plans=plans_log if record else None,
        stage_times=stage_times,
        planner_failures=None if stats is None else stats.failures,
        fallback_frames=tuple(fallback_frames) if reports_stats else None,
        agents=None if traffic is None else traffic.agents,
    ), scenario, config)
