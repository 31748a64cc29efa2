"""fiss-planner's four Frenet planners (FOP, FOP+, FISS, FISS+) behind the plug-in protocol.

Named in a params file as `planner: advperc_ros.contrib.fiss:FissPlanner`, the variant in
`planner_params.variant`; needs the `fiss` extra (fiss-planner, a C++17 core with Python bindings,
numpy only), which shares the main environment. The package's `LocalPlanner` is attacked, not its bare
sampler: it is what a team runs (stitching onto the previous plan, a speed policy, and its own fail-safes:
keep the previous plan, re-plan over a shorter horizon, brake). What the adapter supplies that the
protocol does not carry:

- the reference line: the route, extended straight at both ends, as the package's reference path;
- the corridor: the scenario's lanes that run beside the route, counted to its left and right at one
  lane width each (`lane_width`, the lane nearest the route's start), unless the params name them;
- a prediction of every track: the package plans against time-stamped states only (an obstacle given
  its present state alone is held standing), so each track is predicted by the package's own
  constant-velocity model over its longest horizon and half a second more;
- the failure report: a call in which the package fell back to its previous plan, re-planned over the
  degraded horizon or braked in an emergency counts as a failure (`stats()`), so the search log's
  planner failures and the rulebook's `planner_failure` see the package's own fail-safes.

The package's objects cannot be copied or pickled and its planner carries the previous plan from call
to call, so a rollout of it is not forked from snapshots (`core.forks` rolls it out whole, and says so
once); `reset()` clears that state, so each rollout is a function of its errors alone.
"""

import math
import time
from dataclasses import dataclass

import numpy as np

from advperc_ros.core.planners.base import PlannerStats, PlanningContext, SolveTimes, Trajectory
from advperc_ros.core.planners.parameters import check_ranges, config_from_params
from advperc_ros.core.scenario import EgoState

try:  # at import, so that registry.load_planner reports a missing package as the plug-in's import failing
    import fiss_planner
except ImportError as exc:
    raise ImportError(f"needs fiss-planner (pip install '.[fiss]'): {exc}") from exc

VARIANTS = ("fop", "fop_plus", "fiss", "fiss_plus")
REFERENCE_BEYOND = 200.0  # m the route is extended at each end: a horizon's travel at highway speed
PREDICTION_BEYOND = 0.5  # s a prediction reaches past the longest plan (a box past its last stamp is ignored)
PARALLEL = math.radians(20.0)  # a lane within this of the route's heading (or of its reverse) runs beside it


@dataclass(frozen=True)
class FissConfig:
    """fiss-planner's settings as our params give them; the package's defaults where it has them."""

    variant: str = "fiss_plus"  # fop (Werling et al. 2010), fop_plus, fiss (Sun et al. 2022), fiss_plus (2023)
    target_speed: float = 10.0  # m/s, the desired speed
    lane_width: float = 0.0  # m; 0: the width of the scenario's lane nearest the route's start
    lanes_left: int = -1  # lanes of the corridor left of the route's; -1: counted from the scenario's lanes
    lanes_right: int = -1  # lanes right of it; -1: counted from the scenario's lanes

    def __post_init__(self) -> None:
        if self.variant not in VARIANTS:
            raise ValueError(f"variant must be one of {', '.join(VARIANTS)}, not {self.variant!r}")
        check_ranges(self, non_negative=("target_speed", "lane_width"))
        for name in ("lanes_left", "lanes_right"):
            if (value := getattr(self, name)) < -1:
                raise ValueError(f"{name} must be -1 (counted from the lanes) or a number of lanes, not {value}")


def lanes_beside(context: PlanningContext, width: float) -> tuple[int, int]:
    """(left, right): how many lane widths to either side of the route the scenario's lanes reach, counting
    only lanes that run beside it (either way: an oncoming lane is road to overtake on)."""
    route = context.route
    left = right = 0
    for lane in context.lanes:
        points = lane.centerline.position(np.linspace(0.0, lane.centerline.length, 20))
        s, d = route.project(points)
        beside = (s > 0.0) & (s < route.length)
        if not beside.any():
            continue
        turn = np.abs((lane.centerline.heading(np.linspace(0.0, lane.centerline.length, 20))
                       - route.heading(np.clip(s, 0.0, route.length)) + math.pi) % (2 * math.pi) - math.pi)
        runs_beside = beside & ((turn < PARALLEL) | (turn > math.pi - PARALLEL))
        if runs_beside.sum() < 2:
            continue
        offset = int(round(float(np.median(d[runs_beside])) / width))
        left, right = max(left, offset), max(right, -offset)
    return left, right


class FissPlanner:
    """fiss-planner's LocalPlanner behind our Planner protocol: four published planners nobody here wrote,
    attacked exactly as the bundled ones are."""

    def __init__(self, context: PlanningContext, **params: object) -> None:
        self.context = context
        self.config = config_from_params(FissConfig, params)
        width = self.config.lane_width or self._nearest_lane_width()
        left, right = lanes_beside(context, width)
        config = fiss_planner.LocalPlannerConfig()
        config.planner.type = fiss_planner.planner_type_from_string(self.config.variant)
        config.desired_speed = self.config.target_speed
        config.path.lane_width = width
        config.path.num_left_lanes = left if self.config.lanes_left < 0 else self.config.lanes_left
        config.path.num_right_lanes = right if self.config.lanes_right < 0 else self.config.lanes_right
        vehicle = fiss_planner.VehicleParams()
        vehicle.length, vehicle.width = context.ego_length, context.ego_width
        self._horizon = config.planner.sampling.max_t + PREDICTION_BEYOND
        self._step = config.planner.sampling.dt
        self._planner = fiss_planner.LocalPlanner(config, vehicle)
        route = context.route
        reference = route.position(np.arange(-REFERENCE_BEYOND, route.length + REFERENCE_BEYOND, 1.0))
        self._planner.set_reference_path(np.ascontiguousarray(reference[:, 0]), np.ascontiguousarray(reference[:, 1]))
        self.reset()

    def _nearest_lane_width(self) -> float:
        start = self.context.route.position(0.0)
        if not self.context.lanes:
            return 3.5  # fiss-planner's own default
        gaps = [abs(float(lane.centerline.project(start)[1])) for lane in self.context.lanes]
        return float(self.context.lanes[int(np.argmin(gaps))].width)

    def reset(self) -> None:
        # the package keeps its previous plan (stitching, its fallback): none may pass from one rollout to the next
        self._planner.reset()
        self._failures = 0
        self._solve_times = SolveTimes()

    def stats(self) -> PlannerStats:
        return PlannerStats(failures=self._failures, solve_times=self._solve_times.as_tuple())

    def plan(self, t: float, ego: EgoState, tracks: dict[str, np.ndarray]) -> Trajectory:
        started = time.perf_counter()
        obstacles = [
            fiss_planner.predict_constant_velocity(i, float(x), float(y), float(yaw), math.hypot(vx, vy), float(length),
                                                   float(width), self._horizon, self._step)
            for i, (x, y, yaw, vx, vy, length, width) in enumerate(zip(
                *(np.asarray(tracks[k], float) for k in ("x", "y", "yaw", "vx", "vy", "length", "width"))))
        ]
        out = self._planner.step(t, fiss_planner.EgoState(ego.x, ego.y, ego.yaw, max(ego.v, 0.0)), obstacles,
                                 self.config.target_speed)
        self._solve_times.add(time.perf_counter() - started)
        if not out.success or out.fallback or out.degraded or out.emergency:
            self._failures += 1
        plan = out.trajectory
        if len(plan) < 2:  # nothing to follow, not even a braking plan: the rollout is inconclusive, not a pass
            raise RuntimeError(f"fiss-planner returned a trajectory of {len(plan)} points")
        return Trajectory(t=t + np.asarray(plan.t, float), x=np.asarray(plan.x, float).copy(),
                          y=np.asarray(plan.y, float).copy(), yaw=np.asarray(plan.yaw, float).copy())
