"""The answer to a failed solve, which must still be a plan: the previous plan from now on, if it
reaches a second ahead and misses the predicted tracks, else emergency braking along the previous
path (or the route). Nothing is raised: an attack that makes the NLP fail meets these plans."""

import math

import numpy as np

from advperc_ros.core.geometry import Polyline, box_corners, signed_box_distance, wrap_angle
from advperc_ros.core.planners.base import Trajectory
from advperc_ros.core.planners.obp.config import Setup
from advperc_ros.core.planners.obp.prediction import track_velocities
from advperc_ros.core.scenario import EgoState

FALLBACKS = ("shifted", "braking")


def fallback(setup: Setup, t: float, ego: EgoState, tracks: dict[str, np.ndarray],
             last: Trajectory | None) -> tuple[Trajectory, str]:
    """The plan answering a failed solve at t, and which of FALLBACKS it is."""
    dt = setup.context.dt
    if last is not None and last.t[0] <= t + 1e-9 and last.t[-1] >= t + 1.0 - 1e-9:
        times = t + dt * np.arange(int(math.floor((last.t[-1] - t) / dt + 1e-9)) + 1)
        shifted = Trajectory(t=times, x=np.interp(times, last.t, last.x), y=np.interp(times, last.t, last.y),
                             yaw=np.asarray(wrap_angle(np.interp(times, last.t, np.unwrap(last.yaw))), float))
        if not _collides(setup, shifted, t, tracks):
            return shifted, "shifted"
    return _braking_plan(setup, t, ego, last), "braking"


def _collides(setup: Setup, plan: Trajectory, t: float, tracks: dict[str, np.ndarray]) -> bool:
    """Does the plan's box meet a track's box, grown by the safety margin, predicted as in stage 1?"""
    if len(tracks["x"]) == 0:
        return False
    context = setup.context
    vx, vy = track_velocities(tracks, setup)
    tau = (plan.t - t)[:, None]
    shape = (len(plan.t), len(vx))
    margin = 2.0 * setup.config.safety_margin
    boxes = box_corners(np.asarray(tracks["x"], float) + vx * tau, np.asarray(tracks["y"], float) + vy * tau,
                        np.broadcast_to(tracks["yaw"], shape), np.broadcast_to(tracks["length"] + margin, shape),
                        np.broadcast_to(tracks["width"] + margin, shape))
    ego = box_corners(plan.x, plan.y, plan.yaw, context.ego_length, context.ego_width)
    return bool(np.any(signed_box_distance(np.broadcast_to(ego[:, None], boxes.shape), boxes) <= 0.0))


def _braking_plan(setup: Setup, t: float, ego: EgoState, last: Trajectory | None) -> Trajectory:
    """Braking at max_decel to a standstill along the previous plan's path from the ego, or
    along the route (offset to the ego's lateral position) without one."""
    cfg, dt = setup.config, setup.context.dt
    tau = dt * np.arange(int(round(cfg.horizon / dt)) + 1)
    v0 = max(float(ego.v), 0.0)
    tt = np.minimum(tau, v0 / cfg.max_decel)
    dist = v0 * tt - 0.5 * cfg.max_decel * tt**2
    start = np.array([ego.x, ego.y])
    path = None
    if last is not None:
        ahead = last.t > t + 1e-9
        pts = np.stack([last.x[ahead], last.y[ahead]], axis=1)
        if len(pts) >= 2 and np.linalg.norm(pts[-1] - start) > 0.5:
            end_dir = pts[-1] - pts[-2]
            if np.linalg.norm(end_dir) > 1e-6:
                tail = pts[-1] + 100.0 * end_dir / np.linalg.norm(end_dir)
                path = Polyline(np.vstack([start, pts, tail]))
    if path is not None:
        xy, yaw = path.position(dist), np.array(path.heading(dist), dtype=float)
    else:
        route = setup.context.route
        s0, d0 = route.project(start)
        heading = route.heading(float(s0) + dist)
        xy = route.position(float(s0) + dist) + float(d0) * np.stack([-np.sin(heading), np.cos(heading)], axis=1)
        xy[0], yaw = start, np.array(heading, dtype=float)
    yaw[0] = ego.yaw
    return Trajectory(t=t + tau, x=xy[:, 0].copy(), y=xy[:, 1].copy(), yaw=np.asarray(wrap_angle(yaw), float))
