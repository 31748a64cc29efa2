"""ObP's numbers: the public parameters (`planner_params`, checked at construction), the internal
constants (docs/obp.md lists both), and `Setup`, what follows from them and the planning context
once and every part of the planner shares."""

import math
from dataclasses import dataclass

import numpy as np

from advperc_ros.core.geometry import Polylines
from advperc_ros.core.planners.base import PlanningContext
from advperc_ros.core.planners.obp.road import DrivableBand
from advperc_ros.core.planners.parameters import check_ranges

# the NLP grows with these: past them one solve takes minutes and memory the machine does not have
MAX_HORIZON = 30.0  # s
MAX_OBSTACLES = 64
MAX_ITERATIONS = 10_000

@dataclass(frozen=True)
class OBPConfig:
    """The ObP planner's parameters (a params file's `planner_params`), checked against their ranges."""

    target_speed: float = 10.0  # m/s: the cost drives towards it; also the speed limit
    max_accel: float = 2.0  # m/s^2
    max_decel: float = 5.0  # m/s^2; also the fallback's emergency braking
    max_steer: float = 0.5  # rad, front wheel angle
    max_steer_rate: float = 0.5  # rad/s
    max_jerk: float = 4.0  # m/s^3
    horizon: float = 6.0  # s, of both stages and of the returned plan
    step: float = 0.3  # s, NLP time step, rounded to a whole number of frame periods
    safety_margin: float = 0.2  # m added to every track's half length and half width
    replan_period: float = 0.0  # s; 0 replans on every tracks message, else the last plan is held
    wheelbase: float = 2.7  # m, of the kinematic bicycle
    max_obstacles: int = 3  # obstacle slots of the NLP, given to the tracks nearest the warm start
    max_iterations: int = 60  # IPOPT iteration limit (the deterministic limit)
    max_cpu_time: float = 1.0  # s, IPOPT CPU-time safety net, far above a normal solve
    single_stage: bool = False  # skip stage 1: the NLP alone, warm-started on a straight line

    def __post_init__(self) -> None:
        check_ranges(self, positive=("target_speed", "max_accel", "max_decel", "max_steer", "max_steer_rate",
                                     "max_jerk", "horizon", "step", "wheelbase", "max_obstacles", "max_iterations",
                                     "max_cpu_time"),
                     non_negative=("safety_margin", "replan_period"),
                     at_most={"horizon": MAX_HORIZON, "max_obstacles": MAX_OBSTACLES, "max_iterations": MAX_ITERATIONS})
        if self.max_steer >= math.pi / 2:
            raise ValueError(f"parameter 'max_steer' must be below pi/2 (a front wheel angle), got {self.max_steer!r}")


# Internal constants (documented in docs/obp.md).
STATIC_SPEED = 1.0  # m/s: slower tracks are predicted stationary (the tracker's velocity noise)
LANE_SNAP_ANGLE = 0.25  # rad: a track moving this close to its lane's direction is predicted along it
PASS_SPEED_RATIO = 0.5  # a car in the ego's lane slower than this fraction of target_speed may be passed
ELLIPSE_STRETCH = 1.4  # ellipse semi-major axis / (half length + ego circle radius): length for width
PASS_CLEARANCE = 0.5  # m between the pass path and a passed track's ellipse
RAMP_TIME, RAMP_MIN, RAMP_MAX = 2.5, 12.0, 30.0  # pass path ramps: clip(RAMP_TIME * v0, MIN, MAX) m
STANDSTILL_GAP, HEADWAY = 3.0, 1.0  # stage 1 keeps gap + HEADWAY * v behind cars ahead in the lane
CROSS_BUFFER = 1.0  # m kept from the blocked stations of a yielded-to or gone-before track
MAX_CLASSES = 16  # per lateral path
GRID_STEP = 0.5  # m, station grid of stage 1's blocked-station maps
W1_ACCEL, W1_JERK, W1_LATERAL = 0.05, 0.05, 0.2  # stage 1 cost beyond lost progress (m)
W1_HEADWAY = 10.0  # stage 1 cost per metre of headway shortfall per second: far above lost progress
W_SPEED, W_LATERAL, W_HEADING = 1.0, 1.0, 2.0  # stage 2 tracking weights
W_ACCEL, W_STEER, W_JERK, W_STEER_RATE = 0.2, 2.0, 0.05, 20.0  # stage 2 comfort weights
IPOPT_OPTIONS = {"print_level": 0, "sb": "yes", "tol": 1e-4, "acceptable_tol": 1e-3, "acceptable_iter": 5,
                 "constr_viol_tol": 1e-4, "mu_strategy": "monotone", "mu_init": 1e-2}
SUCCESS = {"Solve_Succeeded", "Solved_To_Acceptable_Level"}
FEASIBLE_ENOUGH = {"Maximum_Iterations_Exceeded"}  # accepted only if the iterate meets the constraints
CONSTRAINT_TOL = 1e-3


@dataclass(frozen=True)
class Setup:
    """The parameters and the context with what follows from them, derived once so that the
    prediction, both stages and the fallback agree on grid, ego shape and road."""

    config: OBPConfig
    context: PlanningContext
    substeps: int  # frame periods per NLP step: the NLP integrates at the frame period
    h: float  # s, the NLP step actually used
    N: int  # NLP steps over the horizon
    stage_t: np.ndarray  # (N+1,) s from the plan time: the grid of both stages
    circle_offsets: np.ndarray  # three circles on the ego's axis cover its box
    circle_radius: float
    road: DrivableBand
    lanes: Polylines  # the lanes' centre lines, every track projected onto all of them at once (`track_velocities`)
    lane_half_widths: np.ndarray  # (L,) m

    @classmethod
    def build(cls, config: OBPConfig, context: PlanningContext) -> "Setup":
        substeps = max(1, int(round(config.step / context.dt)))
        h = substeps * context.dt
        N = max(2, int(round(config.horizon / h)))
        length, width = context.ego_length, context.ego_width
        return cls(config=config, context=context, substeps=substeps, h=h, N=N, stage_t=h * np.arange(N + 1),
                   circle_offsets=np.array([-length / 3.0, 0.0, length / 3.0]),
                   circle_radius=math.hypot(length / 6.0, width / 2.0),
                   road=DrivableBand.around(context.route, context.lanes),
                   lanes=Polylines([lane.centerline for lane in context.lanes]),
                   lane_half_widths=np.array([lane.width / 2.0 for lane in context.lanes]))
