"""What every planner shares: the trajectory it returns, what it knows of the road, the protocol.

A team plugs in its own planner as any class with this protocol, named `module:Class` in the
params file; `registry.load_planner` constructs it as `Class(context, **params)`. A planner may
also report statistics of the current rollout (`stats()`) and take and restore snapshots of its state
(`snapshot()`, `restore()`, so rollouts can fork mid-scenario); one without either still works. This module is
the interface only: it imports no planner, so any module may import it.
"""

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

from advperc_ros.core.geometry import Polyline
from advperc_ros.core.scenario import EgoState, Lane


@dataclass(frozen=True)
class Trajectory:
    """A plan: poses at simulation times t[0] (= plan time) onward; speed is implied by the poses,
    exactly as in the nav_msgs/Path an external planner publishes."""

    t: np.ndarray  # (H,) s
    x: np.ndarray
    y: np.ndarray
    yaw: np.ndarray


EMPTY_PLAN = Trajectory(t=np.zeros(0), x=np.zeros(0), y=np.zeros(0), yaw=np.zeros(0))
"""What a planner node answers when its planner failed: the rollout is then inconclusive."""


@dataclass(frozen=True)
class PlanningContext:
    """The static knowledge a planner is built with: road, route, frame period, ego footprint."""

    route: Polyline
    lanes: tuple[Lane, ...]
    dt: float
    ego_length: float
    ego_width: float


@runtime_checkable
class Planner(Protocol):
    """The protocol every planner under attack has: the search treats the planner as a black box that
    is reset before each rollout and asked for a plan each frame, so any team's planner plugs in."""

    def reset(self) -> None:
        """Forget all state; called before every rollout."""

    def plan(self, t: float, ego: EgoState, tracks: dict[str, np.ndarray]) -> Trajectory:
        """Answer the tracks at time t (dict of 1-D arrays: ids, x, y, yaw, vx, vy, length, width,
        height) with a plan starting at t."""


@dataclass(frozen=True)
class PlannerStats:
    """What a planner reports of the current rollout (since its last reset()): the search log shows
    the failures, benchmarks the solve times."""

    failures: int  # planning calls whose solve failed and that a fallback answered
    solve_times: tuple[float, ...]  # s, wall time of every planning call that planned (not held a plan)


class SolveTimes:
    """The wall time of each planning call of a rollout, for `PlannerStats.solve_times`. A snapshot of a planner
    is taken every frame a forked rollout drives (core.forks), so copying every time so far into each would make
    a rollout's snapshots quadratic in its frames; the times are only ever appended, so a `mark` (the list and
    its length) is the times as they were, in constant time and memory, and `at` makes a new log from one."""

    __slots__ = ("_times",)

    def __init__(self, times: list[float] | None = None) -> None:
        self._times = [] if times is None else times

    def add(self, seconds: float) -> None:
        self._times.append(seconds)

    def mark(self) -> tuple[list[float], int]:
        """The times so far, as a later `at` reads them: the list is shared, and appended to only."""
        return self._times, len(self._times)

    @classmethod
    def at(cls, mark: tuple[list[float], int]) -> "SolveTimes":
        """A log holding the times of `mark`, appended to on its own (`mark` stays as it was)."""
        times, count = mark
        return cls(times[:count])

    def __len__(self) -> int:
        return len(self._times)

    def as_tuple(self) -> tuple[float, ...]:
        return tuple(self._times)


@runtime_checkable
class ReportsStats(Protocol):
    """The optional part of the protocol."""

    def stats(self) -> PlannerStats:
        """Statistics of the current rollout."""


@runtime_checkable
class Snapshots(Protocol):
    """The optional part of the protocol that lets a rollout start mid-scenario (core.forks): a rollout whose
    perception matches an earlier one's up to frame k restores the planner as it was at frame k instead of
    planning frames 0..k-1 again. A planner without it is deep-copied once a forked rollout is checked equal to
    a full one, or rolled out whole (`forks.PlannerSnapshots.of`)."""

    def snapshot(self) -> object:
        """All the state a later `plan` reads, as it is now, sharing nothing that `plan` mutates in place (but
        what is only appended to, kept with its length: `SolveTimes.mark`)."""

    def restore(self, state: object) -> None:
        """Become the planner that took `state`; `state` stays intact, as it may be restored again."""


def planner_stats(planner: Planner) -> PlannerStats | None:
    """The planner's statistics of the current rollout, or None if it keeps none."""
    return planner.stats() if isinstance(planner, ReportsStats) else None
