"""The RolloutResult of a graph rollout, from what the graph published: the same object the
embedded rollout returns, its recorded frames chosen by the same rule (`core.rollout.recorded_frames`)."""

from collections.abc import Callable
from typing import Any

import numpy as np

from advperc_ros.core.planners.base import Trajectory
from advperc_ros.core.rollout import RolloutResult, recorded_frames, violates
from advperc_ros.ros.lockstep import RolloutDone, Status
from advperc_ros.ros.topics import ODOMETRY, PLAN, RULE_DIAGNOSTICS, TRACKING

PER_FRAME = (ODOMETRY, RULE_DIAGNOSTICS)  # what every rollout's result is built from
RECORDED = (TRACKING, PLAN)  # what only recorded rollouts need


def frames_in(received: dict[str, dict[int, Any]], stamps: list[int]) -> int:
    """How many leading frames have both their odometry and rule value in."""
    frames = 0
    while frames < len(stamps) and all(stamps[frames] in received[topic] for topic in PER_FRAME):
        frames += 1
    return frames


def kept_frames(received: dict[str, dict[int, Any]], stamps: list[int], done: RolloutDone,
                stop_at_collision: bool) -> tuple[int, int]:
    """(frames with tracks, frames with a plan) a recorded rollout keeps, as the embedded one."""
    inconclusive = done.status == Status.INCONCLUSIVE
    minimum, _ = received[RULE_DIAGNOSTICS][stamps[done.frames - 1]]
    return recorded_frames(done.frames, not inconclusive and violates(minimum, stop_at_collision), inconclusive)


def complete(received: dict[str, dict[int, Any]], stamps: list[int], done: RolloutDone, record: bool,
             stop_at_collision: bool) -> bool:
    """Whether every message a finished rollout implies is in (/attack/done may overtake them:
    they come from other processes)."""
    if frames_in(received, stamps[: done.frames]) < done.frames:
        return False
    if not record:
        return True
    tracked, planned = kept_frames(received, stamps, done, stop_at_collision)
    return all(s in received[TRACKING] for s in stamps[:tracked]) and all(s in received[PLAN] for s in stamps[:planned])


def assemble(received: dict[str, dict[int, Any]], stamps: list[int], slots: dict[int, int], frames: int,
             inconclusive: str | None, recorded: tuple[int, int] | None, plan: Callable[[int], Trajectory]) -> RolloutResult:
    """The result of `frames` frames: ego states and per-agent signed distances (slot order); with
    `recorded` = (tracked, planned) frames, the tracks and plans too (`plan(stamp)`: the plan of that frame)."""
    ego = np.zeros((frames, 4))
    distances = np.full((frames, len(slots)), np.inf)
    for k, stamp in enumerate(stamps[:frames]):
        state = received[ODOMETRY][stamp]
        ego[k] = (state.x, state.y, state.yaw, state.v)
        _, per_agent = received[RULE_DIAGNOSTICS][stamp]
        for agent, distance in per_agent.items():
            distances[k, slots[agent]] = distance
    result = RolloutResult(ego=ego, distances=distances, inconclusive=inconclusive)
    if recorded is not None:
        tracked, planned = recorded
        result.tracks = [received[TRACKING][s] for s in stamps[:tracked]]
        result.plans = [plan(s) for s in stamps[:planned]]
    return result
