"""Ego motion in the open-loop rollout: the ego follows its latest plan exactly."""

from bisect import bisect_left, bisect_right
from math import isfinite, isnan

import numpy as np

from advperc_ros.core.geometry import wrap_angle
from advperc_ros.core.planners.base import Trajectory
from advperc_ros.core.scenario import EgoState
from advperc_ros.exceptions import PlanError


def follow_plan(plan: Trajectory, t_next: float) -> EgoState:
    """The ego state the plan prescribes at t_next, by linear interpolation between its poses.

    Speed is the central difference of the plan's poses around t_next (half a pose spacing either
    side), so a plan received as a nav_msgs/Path, which has no speeds, is followed identically.
    """
    t = np.asarray(plan.t, dtype=float)
    values = np.array([plan.x, plan.y, plan.yaw], dtype=float)
    if values.shape[1] != t.size:
        raise PlanError(f"plan holds {t.size} timestamps but {values.shape[1]} poses")
    # the poses before the times: a plan timed from its poses' spacing (a distance-sampled Autoware
    # Trajectory) has NaN times where it has NaN poses, and the poses are the cause
    if np.count_nonzero(np.isfinite(values)) != values.size:
        pose = int(np.flatnonzero(~np.isfinite(values).all(axis=0))[0])
        x, y, yaw = values[:, pose]
        raise PlanError(f"plan holds non-finite poses (pose {pose} of {t.size}: x {x}, y {y}, yaw {yaw})")
    steps = t[1:] - t[:-1]
    times = t.tolist()
    # strictly increasing (a nan fails the comparison) between finite ends: finite throughout;
    # counting is cheaper than numpy's reductions on a short plan
    if not (t.size > 1 and np.count_nonzero(steps > 0.0) == steps.size and isfinite(times[0]) and isfinite(times[-1])):
        raise PlanError("plan timestamps must be finite and strictly increasing, at least two poses")
    if not (times[0] - 1e-9 <= t_next <= times[-1] + 1e-9):
        raise PlanError(f"plan covers [{times[0]:.3f}, {times[-1]:.3f}] s, not the next frame at {t_next:.3f} s")
    if np.count_nonzero(np.abs(values[2, 1:] - values[2, :-1]) >= np.pi):  # else np.unwrap changes nothing
        values[2] = np.unwrap(values[2])
    half = 0.5 * float(steps.min())
    before, after = max(times[0], t_next - half), min(times[-1], t_next + half)
    # only the poses around [before, after] (or the plan's end) count: interpolating between them
    # is interpolating in the whole plan, and Python floats of three rows of it cost most of the rest
    first, last = max(bisect_right(times, before) - 1, 0), min(bisect_left(times, after), len(times) - 1)
    times, rows = times[first : last + 1], values[:, first : last + 1].tolist()
    x, y, yaw = _interp(t_next, times, rows)
    (x_before, y_before), (x_after, y_after) = _interp(before, times, rows[:2]), _interp(after, times, rows[:2])
    moved = np.hypot(x_after - x_before, y_after - y_before)
    if not after > before:  # poses a rounding error apart in time: no speed can be read from them
        raise PlanError(f"plan poses around {t_next:.3f} s are too close in time ({half:.3g} s) to give a speed")
    return EgoState(x=x, y=y, yaw=wrap_angle(yaw), v=float(moved / (after - before)))


def _interp(x: float, xp: list[float], rows: list[list[float]]) -> list[float]:
    """np.interp(x, xp, row) of every row, by numpy's own float operations (test_rollout_and_rules
    compares them): one search for all rows, and on a short plan numpy's per-call overhead is most
    of the cost of np.interp. xp increasing; np.interp's default ends: the end values."""
    j = bisect_right(xp, x) - 1
    if j < 0 or j == len(xp) - 1 or xp[j] == x:
        return [row[max(j, 0)] for row in rows]
    out = []
    for row in rows:
        slope = (row[j + 1] - row[j]) / (xp[j + 1] - xp[j])
        value = slope * (x - xp[j]) + row[j]
        if isnan(value):  # as numpy: from the other end, then the flat segment's value
            value = slope * (x - xp[j + 1]) + row[j + 1]
            if isnan(value) and row[j] == row[j + 1]:
                value = row[j]
        out.append(value)
    return out
