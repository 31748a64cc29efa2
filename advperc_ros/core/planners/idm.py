"""IDM path-following planner, after nuPlan's IDMPlanner.

It drives along the route and takes its speed from the Intelligent Driver Model against the
nearest track whose box meets the corridor ahead (the route swept by the ego's width plus a
margin). The lead is assumed to keep its speed along the route over the horizon. The planner
never leaves the route: it can only slow down or stop, which is why dropping the lead vehicle's
detections for long enough makes it collide.
"""

import math
from dataclasses import dataclass

import numpy as np

from advperc_ros.core.planners.base import PlanningContext, Trajectory
from advperc_ros.core.planners.parameters import check_ranges, config_from_params
from advperc_ros.core.scenario import EgoState

MAX_HORIZON = 60.0  # s of plan: a scenario is seconds long, and a plan is sampled every frame of it


@dataclass(frozen=True)
class IDMConfig:
    """The IDM planner's parameters (a params file's `planner_params`), checked against their ranges."""

    target_speed: float = 10.0  # m/s
    min_gap: float = 1.0  # m
    headway: float = 1.5  # s
    max_accel: float = 1.0  # m/s^2
    max_decel: float = 3.0  # m/s^2
    exponent: float = 4.0
    horizon: float = 8.0  # s, at most MAX_HORIZON
    corridor_margin: float = 0.3  # m beyond the ego's half width
    replan_period: float = 0.0  # s; 0 replans on every tracks message

    def __post_init__(self) -> None:
        # target_speed 0 is a planner that only brakes; the gap term divides by sqrt(max_accel * max_decel)
        check_ranges(self, positive=("max_accel", "max_decel", "exponent", "horizon"),
                     non_negative=("target_speed", "min_gap", "headway", "corridor_margin", "replan_period"),
                     at_most={"horizon": MAX_HORIZON})


def idm_acceleration(v: float, v_lead: float | None, gap: float, cfg: IDMConfig) -> float:
    """IDM acceleration, clipped to [-max_decel, max_accel]; v_lead None means free road."""
    free = 1.0 - (v / cfg.target_speed) ** cfg.exponent if cfg.target_speed > 0 else -1.0
    if v_lead is None:
        accel = cfg.max_accel * free
    elif gap <= 0.0:
        accel = -cfg.max_decel
    else:
        dv = v - v_lead
        desired = cfg.min_gap + max(0.0, v * cfg.headway + v * dv / (2.0 * math.sqrt(cfg.max_accel * cfg.max_decel)))
        accel = cfg.max_accel * (free - (desired / gap) ** 2)
    return min(max(accel, -cfg.max_decel), cfg.max_accel)


class IDMPlanner:
    """A lane-following planner with the Intelligent Driver Model's speed law: the simplest planner
    that brakes for what it perceives ahead, so dropping or displacing that detection shows at once."""

    def __init__(self, context: PlanningContext, **params: float) -> None:
        self.context = context
        self.config = config_from_params(IDMConfig, params)
        self.reset()

    def reset(self) -> None:
        self._last: Trajectory | None = None

    def snapshot(self) -> Trajectory | None:
        """The last plan, its only state (a Trajectory is never changed in place)."""
        return self._last

    def restore(self, state: Trajectory | None) -> None:
        self._last = state

    def lead(self, s_ego: float, tracks: dict[str, np.ndarray]) -> tuple[float, float] | None:
        """(gap, speed along the route) of the nearest track in the corridor ahead, or None."""
        if len(tracks["x"]) == 0:
            return None
        route = self.context.route
        s, lateral = route.project(np.stack([tracks["x"], tracks["y"]], axis=1))
        heading = route.heading(s)
        rel = tracks["yaw"] - heading
        half_l, half_w = tracks["length"] / 2.0, tracks["width"] / 2.0
        lat_extent = half_l * np.abs(np.sin(rel)) + half_w * np.abs(np.cos(rel))
        lon_extent = half_l * np.abs(np.cos(rel)) + half_w * np.abs(np.sin(rel))
        corridor = self.context.ego_width / 2.0 + self.config.corridor_margin
        ahead = (s > s_ego) & (np.abs(lateral) - lat_extent < corridor)
        if not ahead.any():
            return None
        gaps = s - lon_extent - (s_ego + self.context.ego_length / 2.0)
        i = np.flatnonzero(ahead)[np.argmin(gaps[ahead])]
        speed = tracks["vx"][i] * np.cos(heading[i]) + tracks["vy"][i] * np.sin(heading[i])
        return float(gaps[i]), max(float(speed), 0.0)

    def plan(self, t: float, ego: EgoState, tracks: dict[str, np.ndarray]) -> Trajectory:
        cfg = self.config
        if self._last is not None and t - self._last.t[0] < cfg.replan_period - 1e-9:
            return self._last
        dt = self.context.dt
        steps = int(round(cfg.horizon / dt))
        s_ego = float(self.context.route.project(np.array([ego.x, ego.y]))[0])
        lead = self.lead(s_ego, tracks)
        gap, v_lead = lead if lead is not None else (np.inf, None)
        s = np.empty(steps + 1)
        v = np.empty(steps + 1)
        s_i, v_i = s_ego, max(float(ego.v), 0.0)
        s[0], v[0] = s_i, v_i
        for i in range(steps):  # plain floats: this loop is the planner's hot path
            accel = idm_acceleration(v_i, v_lead, gap, cfg)
            v_next = max(v_i + accel * dt, 0.0)
            travelled = 0.5 * (v_i + v_next) * dt
            s_i, v_i = s_i + travelled, v_next
            s[i + 1], v[i + 1] = s_i, v_i
            if v_lead is not None:
                gap += v_lead * dt - travelled
        xy = self.context.route.position(s)
        self._last = Trajectory(
            t=t + dt * np.arange(steps + 1), x=xy[:, 0], y=xy[:, 1], yaw=self.context.route.heading(s)
        )
        return self._last
