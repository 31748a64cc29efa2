"""A plug-in planner (`planner: rule_planners:Evader`) that breaks the rules no bundled planner can be made to
break by perception errors: the IDM planner never leaves its route, so it never leaves the road, never drives
the wrong way and never falls back (test_rules_attacked.py)."""

import numpy as np

from advperc_ros.core.planners.base import PlannerStats, PlanningContext, Trajectory
from advperc_ros.core.scenario import EgoState


class Evader:
    """Keeps its speed along its route; a track it sees in its lane up to `reach` m ahead makes it swerve
    to `offset` m beside the route (left positive) at `lateral_speed`, and it stays there. When a track is
    beside it where it would swerve to (within `clearance` m along the route), it is boxed in: it says so
    (a failure in stats(), as a planner whose solver found no way out) and falls back to braking in its lane
    at `fallback_decel`."""

    def __init__(self, context: PlanningContext, offset: float = -3.5, reach: float = 20.0,
                 lateral_speed: float = 1.5, clearance: float = 8.0, fallback_decel: float = 3.0,
                 lane_width: float = 3.5, horizon: float = 3.0) -> None:
        self.context = context
        self.offset, self.reach, self.lateral_speed = float(offset), float(reach), float(lateral_speed)
        self.clearance, self.fallback_decel = float(clearance), float(fallback_decel)
        self.half_lane, self.horizon = float(lane_width) / 2.0, float(horizon)
        self.reset()

    def reset(self) -> None:
        self.swerving = False
        self.failures = 0

    def stats(self) -> PlannerStats:
        return PlannerStats(failures=self.failures, solve_times=())

    def plan(self, t: float, ego: EgoState, tracks: dict[str, np.ndarray]) -> Trajectory:
        route, dt = self.context.route, self.context.dt
        s_ego, lateral_ego = (float(a[0]) for a in route.project(np.array([[ego.x, ego.y]])))
        decel = 0.0
        if not self.swerving and len(tracks["x"]):
            s, lateral = route.project(np.stack([tracks["x"], tracks["y"]], axis=1))
            ahead = (s > s_ego) & (s - s_ego < self.reach) & (np.abs(lateral) < self.half_lane)
            in_the_way = (np.abs(s - s_ego) < self.clearance) & (np.abs(lateral - self.offset) < self.half_lane)
            if ahead.any() and in_the_way.any():
                self.failures += 1
                decel = self.fallback_decel
            elif ahead.any():
                self.swerving = True
        tau = dt * np.arange(round(self.horizon / dt) + 1)
        v0 = max(float(ego.v), 0.0)
        moving = np.minimum(tau, v0 / decel) if decel > 0.0 else tau  # braking stops at rest
        travelled = v0 * moving - 0.5 * decel * moving**2
        target = self.offset if self.swerving else 0.0
        lateral = lateral_ego + np.clip(target - lateral_ego, -self.lateral_speed * tau, self.lateral_speed * tau)
        s_path = s_ego + travelled
        heading = route.heading(s_path)
        centre = route.position(s_path)
        x = centre[:, 0] - np.sin(heading) * lateral
        y = centre[:, 1] + np.cos(heading) * lateral
        yaw = heading + np.arctan2(np.gradient(lateral), np.maximum(np.gradient(s_path), 1e-6))
        return Trajectory(t=t + tau, x=x, y=y, yaw=yaw)
