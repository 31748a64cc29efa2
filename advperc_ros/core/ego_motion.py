"""Ego motion in the open-loop rollout: the ego follows its latest plan exactly."""

import numpy as np

from advperc_ros.core.geometry import wrap_angle
from advperc_ros.core.planners.base import Trajectory
from advperc_ros.core.scenario import EgoState


class PlanError(ValueError):
    """A plan the ego cannot follow; the rollout that received it is inconclusive."""


def follow_plan(plan: Trajectory, t_next: float) -> EgoState:
    """The ego state the plan prescribes at t_next, by linear interpolation between its poses.

    Speed is the central difference of the plan's poses around t_next (half a pose spacing either
    side), so a plan received as a nav_msgs/Path, which has no speeds, is followed identically.
    """
    t = np.asarray(plan.t, dtype=float)
    if t.size < 2 or not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0):
        raise PlanError("plan timestamps must be finite and strictly increasing, at least two poses")
    if not (t[0] - 1e-9 <= t_next <= t[-1] + 1e-9):
        raise PlanError(f"plan covers [{t[0]:.3f}, {t[-1]:.3f}] s, not the next frame at {t_next:.3f} s")
    values = np.stack([plan.x, plan.y, np.unwrap(plan.yaw)])
    if not np.all(np.isfinite(values)):
        raise PlanError("plan holds non-finite poses")
    x, y, yaw = (float(np.interp(t_next, t, row)) for row in values)
    half = 0.5 * float(np.min(np.diff(t)))
    before, after = max(t[0], t_next - half), min(t[-1], t_next + half)
    moved = np.hypot(np.interp(after, t, values[0]) - np.interp(before, t, values[0]),
                     np.interp(after, t, values[1]) - np.interp(before, t, values[1]))
    return EgoState(x=x, y=y, yaw=float(wrap_angle(yaw)), v=float(moved / (after - before)))
