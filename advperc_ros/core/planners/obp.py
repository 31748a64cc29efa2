"""Two-stage optimisation-based planner (ObP), after Eiras et al. 2021, "A two-stage
optimisation-based motion planner for safe urban driving". Formulation and rationale: docs/obp.md.

Stage 1 (global) chooses the manoeuvre class. Tracks are predicted at constant velocity; a slow
car ahead in the ego's lane is either stayed behind or passed on the left (this fixes a lateral
path d(s) along the route), and every track whose predicted ellipse meets that path in the
station-time plane is either yielded to (the ego passes after it) or gone before. Each combination
is a homotopy class whose speed profile along its path is a small LP solved by HiGHS; the cheapest
feasible class becomes the reference.

Stage 2 (local) is an NLP in CasADi solved by IPOPT: a kinematic bicycle over the horizon, tracks
as ellipses that contain their box inflated by the circles covering the ego, road bounds, limits on
speed, acceleration, steering, jerk and steering rate. It is built once with parameters and, on
every call, warm-started from stage 1's reference. A failed solve falls back to the previous plan
shifted to the current time (if it still covers a second and misses the predicted tracks) or to
emergency braking along the previous path; failures are counted in `failures`, nothing is raised.
"""

import math
import time
from dataclasses import dataclass
from itertools import product

import casadi as ca
import numpy as np
from scipy.sparse import csc_matrix

from advperc_ros.core.geometry import Polyline, box_corners, signed_box_distance, wrap_angle
from advperc_ros.core.planners.base import PlannerStats, PlanningContext, Trajectory
from advperc_ros.core.planners.parameters import check_ranges, config_from_params
from advperc_ros.core.scenario import EgoState


@dataclass(frozen=True)
class OBPConfig:
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
                     non_negative=("safety_margin", "replan_period"))
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


def _smoothstep(u: np.ndarray) -> np.ndarray:
    u = np.clip(u, 0.0, 1.0)
    return u * u * (3.0 - 2.0 * u)


def _smoothstep_slope(u: np.ndarray) -> np.ndarray:
    return np.where((u > 0.0) & (u < 1.0), 6.0 * u * (1.0 - u), 0.0)


def ellipse_axes(half_length, half_width, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """Semi-axes (a, b) of ellipses aligned with boxes of these half extents that contain each box
    inflated by a disc of `radius` (their Minkowski sum): a = ELLIPSE_STRETCH (half_length + radius)
    and b the smallest semi-minor axis containing the four rounded corners (found on a grid of the
    corner arcs, then grown by 0.1 % so that no point between grid points pokes out)."""
    hl = np.atleast_1d(np.asarray(half_length, float))
    hw = np.atleast_1d(np.asarray(half_width, float))
    a = ELLIPSE_STRETCH * (hl + radius)
    phi = np.linspace(0.0, 0.5 * np.pi, 181)
    px = hl[:, None] + radius * np.cos(phi)
    py = hw[:, None] + radius * np.sin(phi)
    b = 1.001 * np.max(py / np.sqrt(1.0 - (px / a[:, None]) ** 2), axis=1)
    return a, b


@dataclass
class _Obstacle:
    """A track predicted at constant velocity at the stage times, with its ellipse."""

    id: int
    cx: np.ndarray  # (N+1,) centre at the stage times
    cy: np.ndarray
    yaw: float
    a: float
    b: float
    s: np.ndarray  # route station of the centre at the stage times
    d: np.ndarray  # its lateral offset from the route
    speed_along: float  # velocity along the route at its current position


@dataclass
class _Reference:
    """Stage 1's plan: station, speed and acceleration along the route; lateral offsets."""

    s: np.ndarray
    v: np.ndarray
    a: np.ndarray  # (N,)
    d: np.ndarray  # lateral offset the NLP's cost tracks (the class path)
    slope: np.ndarray  # its derivative along the route
    d_warm: np.ndarray  # the class path blended in from the ego's offset: the NLP's warm start
    slope_warm: np.ndarray
    cost: float
    label: str


class OBPPlanner:
    def __init__(self, context: PlanningContext, **params) -> None:
        self.context = context
        self.config = cfg = config_from_params(OBPConfig, params)
        dt = context.dt
        self.substeps = max(1, int(round(cfg.step / dt)))
        self.h = self.substeps * dt  # the NLP step actually used
        self.N = max(2, int(round(cfg.horizon / self.h)))
        self.stage_t = self.h * np.arange(self.N + 1)
        length, width = context.ego_length, context.ego_width
        self.circle_offsets = np.array([-length / 3.0, 0.0, length / 3.0])  # three circles cover the ego
        self.circle_radius = math.hypot(length / 6.0, width / 2.0)
        self._build_road_table()
        self._build_lp()
        self._build_nlp()
        self.reset()

    def reset(self) -> None:
        self._last: Trajectory | None = None
        self._last_controls: tuple[float, np.ndarray] | None = None  # (plan time, U (2, N)) of the last solve
        self.failures = 0  # failed NLP solves since the last reset (one rollout)
        self.fallbacks = {"shifted": 0, "braking": 0}  # which fallback answered them
        self.solve_times: list[float] = []  # s per planning call, for benchmarks
        self.last_class = ""  # the manoeuvre class stage 1 chose last

    def stats(self) -> PlannerStats:
        return PlannerStats(failures=self.failures, solve_times=tuple(self.solve_times))

    # ------------------------------------------------------------------ road
    def _build_road_table(self) -> None:
        """Drivable lateral band around the route, per metre of station: the route's own lane
        plus the adjacent lane on its left (either direction), as (s, d_right, d_left)."""
        route = self.context.route
        s = np.arange(0.0, route.length + 1.0, 1.0)
        p = route.position(s)
        heading = route.heading(s)
        normal = np.stack([-np.sin(heading), np.cos(heading)], axis=1)
        tangent = np.stack([np.cos(heading), np.sin(heading)], axis=1)
        own_width = np.full(s.shape, 3.5)
        found = np.zeros(s.shape, bool)
        lanes = []
        for lane in self.context.lanes:
            ls, _ = lane.centerline.project(p)
            q = lane.centerline.position(ls) - p
            off = np.einsum("ik,ik->i", q, normal)
            beside = np.abs(np.einsum("ik,ik->i", q, tangent)) < 1.0
            parallel = beside & (np.abs(np.cos(lane.centerline.heading(ls) - heading)) > 0.95)
            own = parallel & (np.abs(off) < 0.2) & ~found
            own_width[own] = lane.width
            found |= own
            lanes.append((off, parallel, lane.width))
        d_left = own_width / 2.0
        for off, parallel, width in lanes:
            adjacent = parallel & (np.abs(off - (own_width + width) / 2.0) < 0.5)
            d_left = np.where(adjacent, np.maximum(d_left, off + width / 2.0), d_left)
        self._road = (s, -own_width / 2.0, d_left)

    def road_bounds(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(d_right, d_left): lateral offsets of the drivable band's edges at stations s."""
        table_s, right, left = self._road
        return np.interp(s, table_s, right), np.interp(s, table_s, left)

    # ------------------------------------------------------------------ stage 2: the NLP, built once
    def _build_nlp(self) -> None:
        cfg, N, h, M, dt = self.config, self.N, self.h, self.config.max_obstacles, self.context.dt
        xs, us = ca.SX.sym("x", 4), ca.SX.sym("u", 2)  # state x, y, yaw, v; controls accel, steer
        rhs = ca.vertcat(xs[3] * ca.cos(xs[2]), xs[3] * ca.sin(xs[2]), xs[3] * ca.tan(us[1]) / cfg.wheelbase, us[0])
        f = ca.Function("f", [xs, us], [rhs])
        xk = xs
        for _ in range(self.substeps):  # RK4 substeps of one frame period each: the plan's poses
            k1 = f(xk, us)
            k2 = f(xk + 0.5 * dt * k1, us)
            k3 = f(xk + 0.5 * dt * k2, us)
            k4 = f(xk + dt * k3, us)
            xk = xk + dt / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
        step = ca.Function("step", [xs, us], [xk])

        X = ca.SX.sym("X", 4, N + 1)
        U = ca.SX.sym("U", 2, N)
        p_uprev = ca.SX.sym("uprev", 2)  # the previous plan's controls now (jerk, steering rate)
        p_frame = ca.SX.sym("frame", 4, N + 1)  # route point and heading (cos, sin) at the reference stations
        p_ref = ca.SX.sym("ref", 3, N + 1)  # reference lateral offset, speed, heading
        p_obs = ca.SX.sym("obs", 2 * M, N + 1)  # predicted centre of each obstacle slot
        p_shape = ca.SX.sym("shape", 4, M)  # cos yaw, sin yaw, 1/a^2, 1/b^2 per slot
        params = ca.vertcat(p_uprev, ca.vec(p_frame), ca.vec(p_ref), ca.vec(p_obs), ca.vec(p_shape))

        g, kinds = [], []  # kinds name each constraint row's bound family; bounds are set per call
        for k in range(N):
            g.append(X[:, k + 1] - step(X[:, k], U[:, k]))
            kinds += ["dyn"] * 4
        g.append((U[:, 0] - p_uprev) / h)
        kinds += ["rate0_a", "rate0_d"]
        for k in range(1, N):
            g.append((U[:, k] - U[:, k - 1]) / h)
            kinds += ["rate_a", "rate_d"]
        cost = 0
        for k in range(1, N + 1):
            px, py, c, s = p_frame[0, k], p_frame[1, k], p_frame[2, k], p_frame[3, k]
            cos_yaw, sin_yaw = ca.cos(X[2, k]), ca.sin(X[2, k])
            for off in (self.circle_offsets[0], self.circle_offsets[-1]):  # road bounds: rear and front circle
                g.append(-(X[0, k] + off * cos_yaw - px) * s + (X[1, k] + off * sin_yaw - py) * c)
                kinds.append("road")
            for j in range(M):
                cj, sj, ia, ib = p_shape[0, j], p_shape[1, j], p_shape[2, j], p_shape[3, j]
                for off in self.circle_offsets:
                    qx = X[0, k] + off * cos_yaw - p_obs[2 * j, k]
                    qy = X[1, k] + off * sin_yaw - p_obs[2 * j + 1, k]
                    lx, ly = cj * qx + sj * qy, -sj * qx + cj * qy
                    g.append(lx * lx * ia + ly * ly * ib)
                    kinds.append("obs")
            d = -(X[0, k] - px) * s + (X[1, k] - py) * c
            cost += W_SPEED * (X[3, k] - p_ref[1, k]) ** 2 + W_LATERAL * (d - p_ref[0, k]) ** 2
            cost += W_HEADING * ca.sin(X[2, k] - p_ref[2, k]) ** 2
        for k in range(N):
            cost += W_ACCEL * U[0, k] ** 2 + W_STEER * U[1, k] ** 2
        for k in range(1, N):
            cost += W_JERK * ((U[0, k] - U[0, k - 1]) / h) ** 2 + W_STEER_RATE * ((U[1, k] - U[1, k - 1]) / h) ** 2
        nlp = {"x": ca.vertcat(ca.vec(X), ca.vec(U)), "p": params, "f": cost * h, "g": ca.vertcat(*g)}
        ipopt = {**IPOPT_OPTIONS, "max_iter": int(cfg.max_iterations), "max_cpu_time": float(cfg.max_cpu_time)}
        opts = {"print_time": False, "ipopt": ipopt}
        self._solver = ca.nlpsol("obp", "ipopt", nlp, opts)
        self._kinds = np.array(kinds)
        self.nlp_size = {"variables": int(nlp["x"].numel()), "constraints": len(kinds),
                         "parameters": int(params.numel())}

    # ------------------------------------------------------------------ prediction
    def _velocities(self, tracks: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
        """Track velocities for the constant-velocity prediction, cleaned of the tracker's noise:
        slower than STATIC_SPEED is stationary; a track inside a lane and moving within
        LANE_SNAP_ANGLE of the lane's direction keeps only its velocity along the lane."""
        vx, vy = np.array(tracks["vx"], float), np.array(tracks["vy"], float)
        speed = np.hypot(vx, vy)
        slow = speed < STATIC_SPEED
        vx[slow], vy[slow] = 0.0, 0.0
        if slow.all():
            return vx, vy
        xy = np.stack([np.asarray(tracks["x"], float), np.asarray(tracks["y"], float)], axis=1)
        nearest = np.full(len(vx), np.inf)
        out_x, out_y = vx.copy(), vy.copy()
        for lane in self.context.lanes:
            ls, lat = lane.centerline.project(xy)
            heading = lane.centerline.heading(ls)
            tx, ty = np.cos(heading), np.sin(heading)
            along = vx * tx + vy * ty
            take = (~slow & (along > math.cos(LANE_SNAP_ANGLE) * speed) & (np.abs(lat) < lane.width / 2.0)
                    & (np.abs(lat) < nearest))
            out_x, out_y = np.where(take, along * tx, out_x), np.where(take, along * ty, out_y)
            nearest = np.where(take, np.abs(lat), nearest)
        return out_x, out_y

    def _predict(self, s0: float, tracks: dict[str, np.ndarray]) -> list[_Obstacle]:
        """Constant-velocity predictions of the tracks that can come near the ego within the horizon.
        Tracks behind the ego that are not closing in are pruned."""
        cfg, t = self.config, self.stage_t
        if len(tracks["x"]) == 0:
            return []
        route = self.context.route
        vx, vy = self._velocities(tracks)
        cx = np.asarray(tracks["x"], float)[:, None] + vx[:, None] * t
        cy = np.asarray(tracks["y"], float)[:, None] + vy[:, None] * t
        s, d = route.project(np.stack([cx, cy], axis=-1))
        heading0 = route.heading(s[:, 0])
        along = vx * np.cos(heading0) + vy * np.sin(heading0)
        a, b = ellipse_axes(np.asarray(tracks["length"]) / 2.0 + cfg.safety_margin,
                            np.asarray(tracks["width"]) / 2.0 + cfg.safety_margin, self.circle_radius)
        v_reach = max(cfg.target_speed, 1.0)
        d_right, d_left = self.road_bounds(np.array([s0]))
        out = []
        for i in range(len(cx)):
            ext = a[i] + self.context.ego_length
            near = ((s[i] > s0 - ext) & (s[i] < s0 + v_reach * t + ext)
                    & (d[i] > d_right[0] - b[i] - 1.0) & (d[i] < d_left[0] + b[i] + 1.0))
            behind_not_closing = s[i, 0] + ext < s0 and along[i] <= cfg.target_speed
            if near.any() and not behind_not_closing:
                out.append(_Obstacle(id=int(tracks["ids"][i]), cx=cx[i], cy=cy[i], yaw=float(tracks["yaw"][i]),
                                     a=float(a[i]), b=float(b[i]), s=s[i], d=d[i], speed_along=float(along[i])))
        return out

    # ------------------------------------------------------------------ stage 1
    def _path(self, s0: float, d0: float, v0: float, passed: list[_Obstacle]):
        """The lateral path of a class: the route, pulled out to the left around every passed
        obstacle (plateau while any ego circle is alongside its ellipse, smoothstep ramps either
        side). With blend_in the ego's current offset is blended in over one ramp length."""
        ramp = float(np.clip(RAMP_TIME * v0, RAMP_MIN, RAMP_MAX))
        front = float(self.circle_offsets[-1])
        bumps = [(float(np.max(ob.d)) + ob.b + PASS_CLEARANCE,
                  float(np.min(ob.s)) - ob.a - front, float(np.max(ob.s)) + ob.a + front) for ob in passed]

        def d_of(s: np.ndarray, blend_in: bool = True) -> tuple[np.ndarray, np.ndarray]:
            d, slope = np.zeros_like(s), np.zeros_like(s)
            for d_pass, s_lo, s_hi in bumps:
                u_in, u_out = (s - (s_lo - ramp)) / ramp, ((s_hi + ramp) - s) / ramp
                rising = u_in < u_out
                u = np.where(rising, u_in, u_out)
                value = d_pass * _smoothstep(u)
                take = value > d
                d = np.where(take, value, d)
                slope = np.where(take, d_pass * _smoothstep_slope(u) / ramp * np.where(rising, 1.0, -1.0), slope)
            if not blend_in:
                return d, slope
            w = 1.0 - _smoothstep((s - s0) / ramp)
            dw = -_smoothstep_slope((s - s0) / ramp) / ramp
            return w * d0 + (1.0 - w) * d, dw * (d0 - d) + (1.0 - w) * slope

        return d_of

    def _blocked(self, grid: np.ndarray, d_of, ob: _Obstacle) -> tuple[np.ndarray, np.ndarray]:
        """Per stage time, the hull [lo, hi] of the ego stations (centre) on the class path at which
        an ego circle lies inside the obstacle's ellipse; nan where there are none."""
        route = self.context.route
        d, slope = d_of(grid)
        heading = route.heading(grid)
        yaw = heading + np.arctan(slope)
        base = route.position(grid) + d[:, None] * np.stack([-np.sin(heading), np.cos(heading)], axis=1)
        cyaw, syaw = math.cos(ob.yaw), math.sin(ob.yaw)
        inside = np.zeros((len(self.stage_t), len(grid)), bool)
        for off in self.circle_offsets:
            qx = (base[:, 0] + off * np.cos(yaw))[None, :] - ob.cx[:, None]
            qy = (base[:, 1] + off * np.sin(yaw))[None, :] - ob.cy[:, None]
            lx, ly = cyaw * qx + syaw * qy, -syaw * qx + cyaw * qy
            inside |= (lx / ob.a) ** 2 + (ly / ob.b) ** 2 < 1.0
        hit = inside.any(axis=1)
        lo = np.where(hit, np.where(inside, grid[None, :], np.inf).min(axis=1), np.nan)
        hi = np.where(hit, np.where(inside, grid[None, :], -np.inf).max(axis=1), np.nan)
        return lo, hi

    def _build_lp(self) -> None:
        """Stage 1's speed LP, built once (HiGHS through CasADi's conic interface); each class
        only changes bounds. Variables: s, v (N+1 each); a, |a|, |jerk| (N each); headway slack (N+1)."""
        N, h = self.N, self.h
        iS, iV, iA = 0, N + 1, 2 * (N + 1)
        iC, iJ = iA + N, iA + 2 * N
        iH = iA + 3 * N
        nvar = iH + N + 1
        rows = []
        for k in range(N):  # dynamics, = 0
            r = np.zeros(nvar)
            r[[iS + k + 1, iS + k, iV + k, iA + k]] = [1.0, -1.0, -h, -0.5 * h * h]
            rows.append(r)
            r = np.zeros(nvar)
            r[[iV + k + 1, iV + k, iA + k]] = [1.0, -1.0, -h]
            rows.append(r)
        n_eq = len(rows)
        for k in range(N):  # |a_k| <= c_k and |a_k - a_{k-1}| <= j_k, <= 0
            for sign in (1.0, -1.0):
                r = np.zeros(nvar)
                r[iA + k], r[iC + k] = sign, -1.0
                rows.append(r)
                if k > 0:
                    r = np.zeros(nvar)
                    r[iA + k], r[iA + k - 1], r[iJ + k] = sign, -sign, -1.0
                    rows.append(r)
        n_abs = len(rows) - n_eq
        for k in range(N + 1):  # following: s_k + HEADWAY v_k - slack_k <= s_lead_k
            r = np.zeros(nvar)
            r[iS + k], r[iV + k], r[iH + k] = 1.0, HEADWAY, -1.0
            rows.append(r)
        A = ca.DM(csc_matrix(np.array(rows)))
        self._lp_A = A
        self._lp = ca.conic("stage1", "highs", {"h": ca.Sparsity(nvar, nvar), "a": A.sparsity()},
                            {"highs": {"output_flag": False}, "error_on_fail": False})
        c = np.zeros(nvar)
        c[iV + 1:iV + N + 1] = -h  # maximise progress
        c[iC:iC + N] = W1_ACCEL * h
        c[iJ:iJ + N] = W1_JERK
        c[iH:iH + N + 1] = W1_HEADWAY * h
        self._lp_cost = c
        self._lp_layout = (iS, iV, iA, iC, iJ, iH, nvar, n_eq, n_abs)

    def _speed_lp(self, s0: float, v0: float, lower: np.ndarray, upper: np.ndarray, s_lead: np.ndarray):
        """Speed profile along the class path: maximise progress, penalise |accel| and |jerk|, with
        the class's bounds on the station per stage time and s_k + HEADWAY v_k <= s_lead_k behind
        cars ahead in the lane, softened by a penalised slack so that a headway already short now (a
        cut-in, a merge) is restored rather than infeasible. Returns (s, v, a, cost) or None."""
        cfg, N, h = self.config, self.N, self.h
        iS, iV, iA, iC, iJ, iH, nvar, n_eq, n_abs = self._lp_layout
        if not (lower[0] <= s0 <= upper[0]):
            return None
        v_cap = max(cfg.target_speed, v0)
        lbx, ubx = np.full(nvar, -np.inf), np.full(nvar, np.inf)
        lbx[iS:iS + N + 1], ubx[iS:iS + N + 1] = lower, upper
        lbx[iV:iV + N + 1], ubx[iV:iV + N + 1] = 0.0, v_cap
        lbx[iS] = ubx[iS] = s0
        lbx[iV] = ubx[iV] = v0
        lbx[iA:iA + N], ubx[iA:iA + N] = -cfg.max_decel, cfg.max_accel
        lbx[iC:iC + N] = 0.0
        lbx[iJ:iJ + N], ubx[iJ:iJ + N] = 0.0, cfg.max_jerk * h
        lbx[iH:iH + N + 1] = 0.0
        lba = np.concatenate([np.zeros(n_eq), np.full(n_abs, -np.inf), np.full(N + 1, -np.inf)])
        uba = np.concatenate([np.zeros(n_eq), np.zeros(n_abs), s_lead])
        sol = self._lp(g=self._lp_cost, a=self._lp_A, lba=lba, uba=uba, lbx=lbx, ubx=ubx)
        if not self._lp.stats().get("success", False):
            return None
        x = np.asarray(sol["x"]).ravel()
        cost = float(np.sum(v_cap - x[iV + 1:iV + N + 1]) * h + W1_ACCEL * h * np.sum(x[iC:iC + N])
                     + W1_JERK * np.sum(x[iJ:iJ + N]) + W1_HEADWAY * h * np.sum(x[iH:iH + N + 1]))
        return x[iS:iS + N + 1], x[iV:iV + N + 1], x[iA:iA + N], cost

    def _stage1(self, s0: float, d0: float, v0: float, obstacles: list[_Obstacle]) -> _Reference | None:
        """Enumerate the homotopy classes, solve each one's speed LP, return the cheapest."""
        cfg, t, front = self.config, self.stage_t, float(self.circle_offsets[-1])
        d_right, _ = self.road_bounds(np.array([s0]))
        lane_half = -float(d_right[0])
        ahead = [ob for ob in obstacles if ob.s[0] + ob.a + front > s0]  # nothing to decide about the rest
        # lateral classes: pass the first n slow cars in the lane ahead (n = 0 .. passable)
        slow = sorted((ob for ob in ahead if abs(ob.d[0]) < lane_half
                       and ob.speed_along < PASS_SPEED_RATIO * cfg.target_speed),
                      key=lambda ob: (ob.s[0], ob.id))
        passable = []
        for ob in slow:
            _, d_left = self.road_bounds(ob.s)
            if float(np.max(ob.d)) + ob.b + PASS_CLEARANCE + self.context.ego_width / 2.0 > float(np.min(d_left)):
                break  # the pulled-out path would leave the road
            passable.append(ob)
        v_reach = max(cfg.target_speed, v0)
        grid = np.arange(s0 - self.context.ego_length, s0 + v_reach * cfg.horizon + 10.0, GRID_STEP)
        t_acc = np.minimum(t, (v_reach - v0) / cfg.max_accel)
        s_max = s0 + v0 * t_acc + 0.5 * cfg.max_accel * t_acc**2 + v_reach * (t - t_acc)  # reachable station
        best: _Reference | None = None
        for n_pass in range(len(passable) + 1):
            passed = passable[:n_pass]
            d_of = self._path(s0, d0, v0, passed)
            decisions, feasible = [], True
            for ob in ahead:
                if any(ob is p for p in passed):
                    continue
                lo, hi = self._blocked(grid, d_of, ob)
                blocked = np.isfinite(lo)
                if not blocked.any():
                    continue
                k1 = int(np.argmax(blocked))
                options = []  # (label, upper bound on s, lower bound on s, bound on s + HEADWAY v)
                in_lane_ahead = abs(ob.d[0]) < lane_half and ob.s[0] > s0
                if in_lane_ahead and ob.speed_along >= STATIC_SPEED:
                    # follow a car in the lane: never into its ellipse (hard), keep the headway (soft)
                    options.append(("follow", np.where(blocked, lo, np.inf), None,
                                    np.where(blocked, lo - STANDSTILL_GAP, np.inf)))
                else:
                    gap = CROSS_BUFFER + (STANDSTILL_GAP if abs(ob.speed_along) < STATIC_SPEED else 0.0)
                    if s0 <= lo[k1] - gap:
                        options.append(("yield", np.where(blocked, lo - gap, np.inf), None, None))
                    if np.all(s_max[blocked] >= hi[blocked] + CROSS_BUFFER):
                        options.append(("go", None, np.where(blocked, hi + CROSS_BUFFER, -np.inf), None))
                if not options:
                    feasible = False  # this path runs into the track whatever the timing
                    break
                decisions.append((ob, options))
            if not feasible:
                continue
            path_label = f"pass{[ob.id for ob in passed]}" if passed else "keep-lane"
            for count, combo in enumerate(product(*(options for _, options in decisions))):
                if count >= MAX_CLASSES:
                    break
                upper, lower = np.full(self.N + 1, np.inf), np.full(self.N + 1, -np.inf)
                s_lead = np.full(self.N + 1, np.inf)
                label = [path_label]
                for (ob, _), (kind, up, low, lead) in zip(decisions, combo):
                    upper = upper if up is None else np.minimum(upper, up)
                    lower = lower if low is None else np.maximum(lower, low)
                    s_lead = s_lead if lead is None else np.minimum(s_lead, lead)
                    label.append(f"{kind}:{ob.id}")
                if np.any(lower > upper):
                    continue
                sol = self._speed_lp(s0, v0, lower, upper, s_lead)
                if sol is None:
                    continue
                s, v, a, cost = sol
                d, slope = d_of(s, blend_in=False)
                cost += W1_LATERAL * float(np.sum(np.abs(d[1:]))) * self.h
                if best is None or cost < best.cost - 1e-9:
                    best = _Reference(s, v, a, d, slope, *d_of(s), cost=cost, label=" ".join(label))
        return best

    def _straight_reference(self, s0: float, d0: float, v0: float, speed: float, label: str) -> _Reference:
        """Along the route at constant acceleration from v0 to `speed` (clipped to the limits)."""
        cfg, t = self.config, self.stage_t
        accel = cfg.max_accel if speed >= v0 else -cfg.max_decel / 2.0
        t_reach = min((speed - v0) / accel, t[-1]) if accel else 0.0
        tt = np.minimum(t, t_reach)
        v = v0 + accel * tt
        s = s0 + v0 * tt + 0.5 * accel * tt**2 + v[-1] * (t - tt)
        zeros, d = np.zeros(self.N + 1), np.full(self.N + 1, d0)
        return _Reference(s, v, np.diff(v) / self.h, zeros if label == "single-stage" else d, zeros, d, zeros,
                          cost=np.inf, label=label)

    # ------------------------------------------------------------------ stage 2 call
    def _solve(self, ego: EgoState, ref: _Reference, obstacles: list[_Obstacle], u_prev: np.ndarray | None):
        cfg, N, M = self.config, self.N, self.config.max_obstacles
        route = self.context.route
        heading = route.heading(ref.s)
        P = route.position(ref.s)
        normal = np.stack([-np.sin(heading), np.cos(heading)], axis=1)
        # warm start: the blended class path at the reference stations and speeds
        warm_xy = P + ref.d_warm[:, None] * normal
        warm_yaw = heading + np.arctan(ref.slope_warm)
        warm_yaw[0] = ego.yaw
        warm_yaw = np.unwrap(warm_yaw)
        travelled = np.diff(ref.s)
        curvature = np.where(travelled > 1e-3, np.diff(warm_yaw) / np.maximum(travelled, 1e-3), 0.0)
        steer = np.clip(np.arctan(cfg.wheelbase * curvature), -cfg.max_steer, cfg.max_steer)
        X0 = np.stack([warm_xy[:, 0], warm_xy[:, 1], warm_yaw, ref.v])
        x0 = np.array([ego.x, ego.y, ego.yaw, max(ego.v, 0.0)])
        X0[:, 0] = x0
        U0 = np.stack([np.clip(ref.a, -cfg.max_decel, cfg.max_accel), steer])
        # obstacle slots: the tracks nearest the warm start; unused slots are unit circles far away
        dist = [float(np.min(np.hypot(ob.cx - warm_xy[:, 0], ob.cy - warm_xy[:, 1]))) for ob in obstacles]
        order = sorted(range(len(obstacles)), key=lambda i: (dist[i], obstacles[i].id))[:M]
        obs = np.zeros((2 * M, N + 1))
        shape = np.tile(np.array([[1.0], [0.0], [1.0], [1.0]]), (1, M))
        for slot in range(M):
            if slot < len(order):
                ob = obstacles[order[slot]]
                obs[2 * slot], obs[2 * slot + 1] = ob.cx, ob.cy
                shape[:, slot] = [math.cos(ob.yaw), math.sin(ob.yaw), 1.0 / ob.a**2, 1.0 / ob.b**2]
            else:
                obs[2 * slot], obs[2 * slot + 1] = ego.x + 1e4 + 100.0 * slot, ego.y + 1e4
        frame = np.stack([P[:, 0], P[:, 1], np.cos(heading), np.sin(heading)])
        reference = np.stack([ref.d, ref.v, heading + np.arctan(ref.slope)])
        p = np.concatenate([np.zeros(2) if u_prev is None else u_prev, frame.ravel(order="F"),
                            reference.ravel(order="F"), obs.ravel(order="F"), shape.ravel(order="F")])
        # bounds: states and controls, then the constraint rows by family
        lbx = np.tile([-np.inf, -np.inf, -np.inf, 0.0], N + 1)
        ubx = np.tile([np.inf, np.inf, np.inf, max(cfg.target_speed, x0[3])], N + 1)
        lbx[:4] = ubx[:4] = x0
        lbw = np.concatenate([lbx, np.tile([-cfg.max_decel, -cfg.max_steer], N)])
        ubw = np.concatenate([ubx, np.tile([cfg.max_accel, cfg.max_steer], N)])
        kinds = self._kinds
        lbg, ubg = np.zeros(kinds.size), np.zeros(kinds.size)
        first = 1.0 if u_prev is not None else np.inf  # no previous controls: the first rates are free
        for name, limit in (("rate_a", cfg.max_jerk), ("rate_d", cfg.max_steer_rate),
                            ("rate0_a", cfg.max_jerk * first), ("rate0_d", cfg.max_steer_rate * first)):
            lbg[kinds == name], ubg[kinds == name] = -limit, limit
        d_right, d_left = self.road_bounds(ref.s[1:])
        half_width = self.context.ego_width / 2.0
        lbg[kinds == "road"] = np.repeat(d_right + half_width, 2)
        ubg[kinds == "road"] = np.repeat(d_left - half_width, 2)
        lbg[kinds == "obs"], ubg[kinds == "obs"] = 1.0, np.inf
        w0 = np.concatenate([X0.ravel(order="F"), U0.ravel(order="F")])
        sol = self._solver(x0=w0, p=p, lbx=lbw, ubx=ubw, lbg=lbg, ubg=ubg)
        status = self._solver.stats().get("return_status", "")
        w = np.asarray(sol["x"]).ravel()
        gval = np.asarray(sol["g"]).ravel()
        violation = max(float(np.max(lbg - gval)), float(np.max(gval - ubg)), 0.0)
        ok = bool(np.all(np.isfinite(w)) and (status in SUCCESS or status in FEASIBLE_ENOUGH)
                  and violation <= CONSTRAINT_TOL)
        n_x = 4 * (N + 1)
        return ok, w[:n_x].reshape(N + 1, 4).T, w[n_x:].reshape(N, 2).T, status

    def _resample(self, t: float, X: np.ndarray, U: np.ndarray) -> Trajectory:
        """Poses every frame period: the NLP's own RK4 substeps from each node."""
        dt, L = self.context.dt, self.config.wheelbase
        states = [X[:, 0]]
        for k in range(self.N):
            z = X[:, k].copy()
            accel, tan_steer = float(U[0, k]), math.tan(float(U[1, k]))

            def f(q: np.ndarray) -> np.ndarray:
                return np.array([q[3] * math.cos(q[2]), q[3] * math.sin(q[2]), q[3] * tan_steer / L, accel])

            for _ in range(self.substeps - 1):
                k1 = f(z)
                k2 = f(z + 0.5 * dt * k1)
                k3 = f(z + 0.5 * dt * k2)
                k4 = f(z + dt * k3)
                z = z + dt / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
                states.append(z)
            states.append(X[:, k + 1])
        S = np.array(states)
        return Trajectory(t=t + dt * np.arange(len(S)), x=S[:, 0].copy(), y=S[:, 1].copy(),
                          yaw=np.asarray(wrap_angle(S[:, 2]), dtype=float))

    # ------------------------------------------------------------------ fallback
    def _collides(self, plan: Trajectory, t: float, tracks: dict[str, np.ndarray]) -> bool:
        """Does the plan's box meet a track's box, grown by the safety margin, predicted as in stage 1?"""
        if len(tracks["x"]) == 0:
            return False
        vx, vy = self._velocities(tracks)
        tau = (plan.t - t)[:, None]
        shape = (len(plan.t), len(vx))
        margin = 2.0 * self.config.safety_margin
        boxes = box_corners(np.asarray(tracks["x"], float) + vx * tau, np.asarray(tracks["y"], float) + vy * tau,
                            np.broadcast_to(tracks["yaw"], shape), np.broadcast_to(tracks["length"] + margin, shape),
                            np.broadcast_to(tracks["width"] + margin, shape))
        ego = box_corners(plan.x, plan.y, plan.yaw, self.context.ego_length, self.context.ego_width)
        return bool(np.any(signed_box_distance(np.broadcast_to(ego[:, None], boxes.shape), boxes) <= 0.0))

    def _fallback(self, t: float, ego: EgoState, tracks: dict[str, np.ndarray]) -> Trajectory:
        """The previous plan from t on, if it reaches a second ahead and misses the predicted
        tracks; otherwise emergency braking."""
        dt, last = self.context.dt, self._last
        if last is not None and last.t[0] <= t + 1e-9 and last.t[-1] >= t + 1.0 - 1e-9:
            times = t + dt * np.arange(int(math.floor((last.t[-1] - t) / dt + 1e-9)) + 1)
            shifted = Trajectory(t=times, x=np.interp(times, last.t, last.x), y=np.interp(times, last.t, last.y),
                                 yaw=np.asarray(wrap_angle(np.interp(times, last.t, np.unwrap(last.yaw))), float))
            if not self._collides(shifted, t, tracks):
                self.fallbacks["shifted"] += 1
                return shifted
        self.fallbacks["braking"] += 1
        return self._braking_plan(t, ego)

    def _braking_plan(self, t: float, ego: EgoState) -> Trajectory:
        """Braking at max_decel to a standstill along the previous plan's path from the ego, or
        along the route (offset to the ego's lateral position) without one."""
        cfg, dt = self.config, self.context.dt
        tau = dt * np.arange(int(round(cfg.horizon / dt)) + 1)
        v0 = max(float(ego.v), 0.0)
        tt = np.minimum(tau, v0 / cfg.max_decel)
        dist = v0 * tt - 0.5 * cfg.max_decel * tt**2
        start = np.array([ego.x, ego.y])
        path = None
        if self._last is not None:
            ahead = self._last.t > t + 1e-9
            pts = np.stack([self._last.x[ahead], self._last.y[ahead]], axis=1)
            if len(pts) >= 2 and np.linalg.norm(pts[-1] - start) > 0.5:
                end_dir = pts[-1] - pts[-2]
                if np.linalg.norm(end_dir) > 1e-6:
                    tail = pts[-1] + 100.0 * end_dir / np.linalg.norm(end_dir)
                    path = Polyline(np.vstack([start, pts, tail]))
        if path is not None:
            xy, yaw = path.position(dist), np.array(path.heading(dist), dtype=float)
        else:
            route = self.context.route
            s0, d0 = route.project(start)
            heading = route.heading(float(s0) + dist)
            xy = route.position(float(s0) + dist) + float(d0) * np.stack([-np.sin(heading), np.cos(heading)], axis=1)
            xy[0], yaw = start, np.array(heading, dtype=float)
        yaw[0] = ego.yaw
        return Trajectory(t=t + tau, x=xy[:, 0].copy(), y=xy[:, 1].copy(), yaw=np.asarray(wrap_angle(yaw), float))

    # ------------------------------------------------------------------ protocol
    def plan(self, t: float, ego: EgoState, tracks: dict[str, np.ndarray]) -> Trajectory:
        cfg = self.config
        last = self._last
        if last is not None and t - last.t[0] < cfg.replan_period - 1e-9 and last.t[-1] >= t + self.context.dt:
            return last
        started = time.perf_counter()
        s0, d0 = (float(v) for v in self.context.route.project(np.array([ego.x, ego.y])))
        v0 = max(float(ego.v), 0.0)
        obstacles = self._predict(s0, tracks)
        if cfg.single_stage:
            ref = self._straight_reference(s0, d0, v0, cfg.target_speed, "single-stage")
        else:
            ref = self._stage1(s0, d0, v0, obstacles)
            if ref is None:  # no feasible class: warm start on braking in place, the NLP may still succeed
                ref = self._straight_reference(s0, d0, v0, 0.0, "no-class")
        self.last_class = ref.label
        u_prev = None
        if self._last_controls is not None:
            t_ctrl, U_last = self._last_controls
            k = int(math.floor((t - t_ctrl) / self.h + 1e-9))
            if 0 <= k < U_last.shape[1]:
                u_prev = U_last[:, k].copy()
        try:
            ok, X, U, _ = self._solve(ego, ref, obstacles, u_prev)
        except RuntimeError:  # CasADi reports an IPOPT error: a failed solve like any other
            ok = False
        if ok:
            plan = self._resample(t, X, U)
            self._last_controls = (t, U)
        else:
            self.failures += 1
            plan = self._fallback(t, ego, tracks)
            self._last_controls = None
        self._last = plan
        self.solve_times.append(time.perf_counter() - started)
        return plan
