"""TUM's `commonroad-reactive-planner` (a sampling-based Frenet planner) behind the plug-in protocol.

Named in a params file as `planner: advperc_ros.contrib.reactive:ReactivePlanner`; needs the
`reactive` extra, which pins commonroad-io below the version the importer is tested with, so it
lives in an environment of its own (README, "Dependencies and why"). What the adapter supplies that
the protocol does not carry:

- a reference path: the route, as the planner's curvilinear frame (built once), and a new sampler
  for each rollout, so that no state of the package passes from one rollout to the next;
- a collision checker per call: every track's box over the horizon at its tracked velocity (the
  planner itself has no prediction), no road boundary (the protocol gives lanes as centre lines
  and widths, not a lanelet network; the planner's lateral samples stay within `lateral` m of the
  route anyway);
- its full initial state: the protocol's ego has pose and speed only, so acceleration and steering
  come from the previous plan at t (0 at the first call), and positions move between the ego's
  centre and the planner's rear axle;
- a desired speed at standstill: at exactly 0 m/s the planner reads it from the planning problem
  (the goal), which the interface does not carry, so a standing ego is passed as creeping at 1 mm/s;
- an answer when every sample collides: the planner returns nothing, and a plan is needed, so the
  adapter brakes at `emergency_decel` along the previous plan's path (or the route) and counts a
  failure (stats()).
"""

import logging
import math
import time
from dataclasses import dataclass

import numpy as np

from advperc_ros.core.geometry import Polyline, wrap_angle
from advperc_ros.core.planners.base import PlannerStats, PlanningContext, SolveTimes, Trajectory
from advperc_ros.core.planners.parameters import check_ranges, config_from_params
from advperc_ros.core.scenario import EgoState

try:  # at import, so that registry.load_planner reports a missing package as the plug-in's import failing
    import commonroad_dc.pycrcc as pycrcc
    from commonroad.scenario.scenario import Scenario
    from commonroad_rp.reactive_planner import ReactivePlanner as Sampler
    from commonroad_rp.state import ReactivePlannerState
    from commonroad_rp.utility.config import ReactivePlannerConfiguration
    from commonroad_rp.utility.utils_coordinate_system import create_coordinate_system
except ImportError as exc:
    raise ImportError(f"needs commonroad-reactive-planner (pip install '.[reactive]' in an environment of its "
                      f"own): {exc}") from exc


REFERENCE_BEYOND = 200.0  # m: 6 s at 33 m/s, any horizon this adapter is given at highway speed
STANDING = 1e-3  # m/s, the speed a standing ego is given to the planner's speed sampling (see plan)


@dataclass(frozen=True)
class ReactiveConfig:
    """The third-party reactive planner's settings as our params give them; the defaults trade its
    own planning horizon for an attack's thousands of calls."""

    target_speed: float = 10.0  # m/s, the planner's desired velocity
    horizon: float = 3.0  # s (the package's default is 6 s; 3 s keeps an attack's thousands of calls affordable)
    lateral: float = 3.0  # m, the largest lateral offset from the route sampled
    emergency_decel: float = 8.0  # m/s^2, braking when no sample is collision-free
    replan_period: float = 0.3  # s; the package's own loop replans every 3rd step; 0 replans on every tracks message

    def __post_init__(self) -> None:
        check_ranges(self, positive=("horizon", "lateral", "emergency_decel"),
                     non_negative=("target_speed", "replan_period"))


class ReactivePlanner:
    """TUM's commonroad-reactive-planner behind our Planner protocol: a planner we did not write, attacked
    exactly as the bundled ones are, which shows a team's planner plugs in the same way."""

    def __init__(self, context: PlanningContext, **params: float) -> None:
        self.context = context
        self.config = config_from_params(ReactiveConfig, params)
        steps = int(round(self.config.horizon / context.dt))
        planner_config = ReactivePlannerConfiguration()
        planner_config.planning.dt, planner_config.planning.time_steps_computation = context.dt, steps
        planner_config.planning.planning_horizon = context.dt * steps
        planner_config.sampling.d_min, planner_config.sampling.d_max = -self.config.lateral, self.config.lateral
        planner_config.vehicle.length, planner_config.vehicle.width = context.ego_length, context.ego_width
        planner_config.debug.multiproc = False  # its default, 6 workers, would swamp a shared machine
        planner_config.debug.logging_level = "ERROR"
        planner_config.scenario = Scenario(dt=context.dt)  # obstacles come per call, not from a scenario
        self._planner_config = planner_config
        logging.getLogger("RP_LOGGER").setLevel(logging.ERROR)
        # the route every metre (the curvilinear frame wants >= 3 points; a straight route has 2), extended
        # straight at both ends: a plan or a track beyond the frame's ends makes the planner raise
        route, beyond = context.route, REFERENCE_BEYOND
        reference = route.position(np.arange(-beyond, route.length + beyond, 1.0))
        with np.errstate(divide="ignore"):  # its own smoothing, which divides by a straight route's zero curvature
            self._coordinate_system = create_coordinate_system(reference)
        self._rear = planner_config.vehicle.wb_rear_axle  # m from the centre back to the rear axle
        self._steps = steps
        self.reset()

    def reset(self) -> None:
        # a new sampler each rollout (0.1 ms): the package carries state from call to call (its low-speed
        # mode, read when it converts the next call's initial state), which must not pass from one
        # rollout to the next, or a replay or another worker would not see what the search saw
        self._sampler = Sampler(self._planner_config)
        self._sampler.set_reference_path(coordinate_system=self._coordinate_system)
        self._last: Trajectory | None = None
        self._last_states: list | None = None
        self._failures = 0
        self._solve_times = SolveTimes()

    def stats(self) -> PlannerStats:
        return PlannerStats(failures=self._failures, solve_times=self._solve_times.as_tuple())

    def snapshot(self) -> tuple:
        """The last plan and its states, the statistics, and what the package's sampler carries from one call to
        the next: its low-speed mode and desired speed (every other attribute it sets anew in each call)."""
        sampler = self._sampler
        return (self._last, self._last_states, self._failures, self._solve_times.mark(), sampler._low_vel_mode,
                sampler._desired_speed)

    def restore(self, state: tuple) -> None:
        self._last, self._last_states, self._failures, solve_times, low_speed, desired_speed = state
        self._solve_times = SolveTimes.at(solve_times)
        self._sampler._low_vel_mode, self._sampler._desired_speed = low_speed, desired_speed

    def plan(self, t: float, ego: EgoState, tracks: dict[str, np.ndarray]) -> Trajectory:
        if self._last is not None and t - self._last.t[0] < self.config.replan_period - 1e-9:
            return self._last
        started = time.perf_counter()
        dt = self.context.dt
        previous = self._previous_state(t)
        state = ReactivePlannerState(
            time_step=0,
            position=np.array([ego.x - self._rear * math.cos(ego.yaw), ego.y - self._rear * math.sin(ego.yaw)]),
            orientation=ego.yaw, velocity=max(ego.v, 0.0),
            acceleration=0.0 if previous is None else float(previous.acceleration),
            steering_angle=0.0 if previous is None else float(previous.steering_angle),
            yaw_rate=0.0 if previous is None else float(previous.yaw_rate),
        )
        self._sampler.reset(initial_state_cart=state, initial_state_curv=None,
                            collision_checker=self._collision_checker(tracks))
        # at exactly 0 m/s it looks its desired speed up in the CommonRoad planning problem, which the
        # interface does not carry: a standing ego is given as creeping at STANDING
        self._sampler.set_desired_velocity(self.config.target_speed, current_speed=max(state.velocity, STANDING))
        result = self._sampler.plan()
        self._solve_times.add(time.perf_counter() - started)
        if result is None:
            self._failures += 1
            self._last, self._last_states = self._braking(t, ego), None
            return self._last
        states = result[0].state_list
        yaw = np.array([s.orientation for s in states])
        xy = np.array([s.position for s in states]) + self._rear * np.stack([np.cos(yaw), np.sin(yaw)], axis=1)
        self._last = Trajectory(t=t + dt * np.array([s.time_step for s in states], float), x=xy[:, 0], y=xy[:, 1],
                                yaw=np.asarray(wrap_angle(yaw), float))
        self._last_states = states
        return self._last

    def _previous_state(self, t: float):
        """The previous plan's state at t (for acceleration and steering), if it planned one then."""
        if self._last is None or self._last_states is None:
            return None
        k = int(round((t - self._last.t[0]) / self.context.dt))
        return self._last_states[k] if 0 <= k < len(self._last_states) else None

    def _collision_checker(self, tracks: dict[str, np.ndarray]):
        """Every track's box at steps 0..horizon, moving at its tracked velocity."""
        checker = pycrcc.CollisionChecker()
        tau = self.context.dt * np.arange(self._steps + 1)
        for x, y, yaw, vx, vy, length, width in zip(*(np.asarray(tracks[k], float) for k in
                                                      ("x", "y", "yaw", "vx", "vy", "length", "width"))):
            moving = pycrcc.TimeVariantCollisionObject(0)
            for step in tau:
                moving.append_obstacle(pycrcc.RectOBB(length / 2, width / 2, yaw, x + vx * step, y + vy * step))
            checker.add_collision_object(moving)
        return checker

    def _braking(self, t: float, ego: EgoState) -> Trajectory:
        """Braking at emergency_decel to a standstill along the previous plan's path from the ego, else
        along the route from the ego's projection onto it."""
        decel, dt = self.config.emergency_decel, self.context.dt
        tau = dt * np.arange(self._steps + 1)
        v0 = max(float(ego.v), 0.0)
        stop = np.minimum(tau, v0 / decel)
        distance = v0 * stop - 0.5 * decel * stop**2
        start = np.array([ego.x, ego.y])
        path, offset = self.context.route, float(self.context.route.project(start)[0])
        if self._last is not None:
            ahead = self._last.t > t + 1e-9
            points = np.vstack([start, np.stack([self._last.x[ahead], self._last.y[ahead]], axis=1)])
            if len(points) >= 2 and np.linalg.norm(points[-1] - start) > 0.5:
                path, offset = Polyline(points), 0.0  # Polyline extends its end segment beyond the last pose
        xy = path.position(offset + distance)
        yaw = np.array(path.heading(offset + distance), float)
        xy[0], yaw[0] = start, ego.yaw
        return Trajectory(t=t + tau, x=xy[:, 0].copy(), y=xy[:, 1].copy(), yaw=np.asarray(wrap_angle(yaw), float))
