"""Stage 2: a kinematic-bicycle NLP in CasADi, solved by IPOPT, with the tracks as ellipses the
ego's circles stay out of, road bounds and limits on speed, acceleration, steering, jerk and
steering rate. Built once with parameters; each call sets parameters, bounds and the warm start
from stage 1's reference. Formulation: docs/obp.md."""

import math
from typing import Any

import casadi as ca
import numpy as np

from advperc_ros.core.geometry import wrap_angle
from advperc_ros.core.planners.base import Trajectory
from advperc_ros.core.planners.obp.compiled import compiled_solver
from advperc_ros.core.planners.obp.config import (
    CONSTRAINT_TOL,
    FEASIBLE_ENOUGH,
    IPOPT_OPTIONS,
    SUCCESS,
    W_ACCEL,
    W_HEADING,
    W_JERK,
    W_LATERAL,
    W_SPEED,
    W_STEER,
    W_STEER_RATE,
    Setup,
)
from advperc_ros.core.planners.obp.dynamics import NUMERIC, SYMBOLIC, bicycle_rk4
from advperc_ros.core.planners.obp.prediction import Obstacle
from advperc_ros.core.planners.obp.stage1 import Reference
from advperc_ros.core.scenario import EgoState


class Stage2:
    """ObP's second stage: the NLP over the bicycle model that smooths stage 1's reference into a
    drivable plan, compiled once per planner (CasADi) because it runs every frame."""

    def __init__(self, setup: Setup) -> None:
        self.setup = setup
        cfg, N, h, M, dt = setup.config, setup.N, setup.h, setup.config.max_obstacles, setup.context.dt
        xs, us = ca.SX.sym("x", 4), ca.SX.sym("u", 2)  # state x, y, yaw, v; controls accel, steer
        # RK4 substeps of one frame period each, as `resample` takes the plan's poses between nodes
        xk = bicycle_rk4(xs, us[0], us[1], dt, cfg.wheelbase, setup.substeps, SYMBOLIC)[-1]
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
        cost: ca.SX | float = 0  # a CasADi expression from its first term on
        for k in range(1, N + 1):
            px, py, c, s = p_frame[0, k], p_frame[1, k], p_frame[2, k], p_frame[3, k]
            cos_yaw, sin_yaw = ca.cos(X[2, k]), ca.sin(X[2, k])
            for off in (setup.circle_offsets[0], setup.circle_offsets[-1]):  # road bounds: rear and front circle
                g.append(-(X[0, k] + off * cos_yaw - px) * s + (X[1, k] + off * sin_yaw - py) * c)
                kinds.append("road")
            for j in range(M):
                cj, sj, ia, ib = p_shape[0, j], p_shape[1, j], p_shape[2, j], p_shape[3, j]
                for off in setup.circle_offsets:
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
        variables = ca.vertcat(ca.vec(X), ca.vec(U))
        nlp: dict[str, ca.SX | float] = {"x": variables, "p": params, "f": cost * h, "g": ca.vertcat(*g)}
        ipopt = {**IPOPT_OPTIONS, "max_iter": int(cfg.max_iterations), "max_cpu_time": float(cfg.max_cpu_time)}
        opts: dict[str, Any] = {"print_time": False, "ipopt": ipopt}
        self._solver = compiled_solver("obp", ca.nlpsol("obp", "ipopt", nlp, opts), opts)
        self._kinds = np.array(kinds)
        self.size = {"variables": int(variables.numel()), "constraints": len(kinds), "parameters": int(params.numel())}

    def solve(self, ego: EgoState, ref: Reference, obstacles: list[Obstacle],
              u_prev: np.ndarray | None) -> tuple[bool, np.ndarray, np.ndarray]:
        """(accepted, states X (4, N+1), controls U (2, N)) of one solve warm-started on `ref`;
        u_prev, the previous plan's controls now, bounds the first jerk and steering rate. A problem
        `certainly_infeasible` proves infeasible is not solved: it fails with the warm start."""
        setup = self.setup
        cfg, N, M = setup.config, setup.N, setup.config.max_obstacles
        route = setup.context.route
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
        if certainly_infeasible(setup, ego, obs, shape):  # IPOPT would spend its iterations finding that out
            return False, X0, U0
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
        d_right, d_left = setup.road.bounds(ref.s[1:])
        half_width = setup.context.ego_width / 2.0
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
        return ok, w[:n_x].reshape(N + 1, 4).T, w[n_x:].reshape(N, 2).T


def certainly_infeasible(setup: Setup, ego: EgoState, obs: np.ndarray, shape: np.ndarray) -> bool:
    """Whether, at some node, an obstacle slot's ellipse (centres `obs` (2M, N+1), shapes `shape` (4, M)
    as the NLP's parameters hold them) covers every point one of the ego's circles can reach from `ego`
    within the NLP's bounds, so that no iterate meets the constraints to CONSTRAINT_TOL and IPOPT could
    only fail, after up to max_iterations iterations (most of an attack's failed solves: the errors put a
    car onto the ego). Sound by construction, never complete: docs/obp.md, "Infeasible at once"."""
    cfg, N, h, tol = setup.config, setup.N, setup.h, CONSTRAINT_TOL
    v0 = max(float(ego.v), 0.0)
    k = np.arange(1, N + 1)
    # every speed up to node k: the bounds, the acceleration limit, the dynamics rows' tolerance per step
    speed = np.minimum(max(cfg.target_speed, v0), v0 + cfg.max_accel * h * k) + tol * k
    reach = np.cumsum(h * speed)  # longest path to node k
    turn = np.cumsum(h * speed * math.tan(cfg.max_steer) / cfg.wheelbase) + tol * k  # largest heading change
    # the positions lie in the sector of radius `reach` and half-angle `turn` ahead of the ego, inside the
    # disk through its apex and its arc's ends; past a radian, the disk of radius `reach` about the ego
    sector = turn < 1.0
    ahead = np.where(sector, reach / 2.0, 0.0)
    # plus what the sector leaves out: each node's position row off by up to tol in x and y, and a speed
    # between nodes as low as -tol (a node's is at least 0, the row to the next off by tol), h * tol backwards
    radius = np.where(sector, reach * np.sqrt(1.25 - np.cos(np.minimum(turn, 1.0))), reach) + (2.0 + h) * tol * k
    c, s = math.cos(ego.yaw), math.sin(ego.yaw)
    level = 1.0 - 2.0 * tol  # a point with the ellipse row below this violates it by more than tol
    for offset in setup.circle_offsets:
        centre_x, centre_y = ego.x + (ahead + offset) * c, ego.y + (ahead + offset) * s
        spread = radius + abs(offset) * np.minimum(turn, 2.0)  # the circle turns about the ego's centre
        for j in range(shape.shape[1]):
            cj, sj, ia, ib = shape[:, j]
            qx, qy = centre_x - obs[2 * j, 1:], centre_y - obs[2 * j + 1, 1:]
            lx, ly = cj * qx + sj * qy, -sj * qx + cj * qy
            # the disk lies in {row < level} if its centre lies in that ellipse scaled by 1 - spread / semi-minor
            minor = math.sqrt(level) / math.sqrt(max(ia, ib))
            inside = (spread < minor) & (lx * lx * ia + ly * ly * ib < level * (1.0 - spread / minor) ** 2)
            if bool(np.any(inside)):
                return True
    return False


def resample(setup: Setup, t: float, X: np.ndarray, U: np.ndarray) -> Trajectory:
    """Poses every frame period: the NLP's own RK4 substeps from each node."""
    dt, wheelbase = setup.context.dt, setup.config.wheelbase
    states = [X[:, 0]]
    for k in range(setup.N):
        states += bicycle_rk4(X[:, k], float(U[0, k]), float(U[1, k]), dt, wheelbase, setup.substeps - 1, NUMERIC)
        states.append(X[:, k + 1])  # the NLP's node: its last substep
    S = np.array(states)
    return Trajectory(t=t + dt * np.arange(len(S)), x=S[:, 0].copy(), y=S[:, 1].copy(),
                      yaw=np.asarray(wrap_angle(S[:, 2]), dtype=float))
