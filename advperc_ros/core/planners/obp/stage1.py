"""Stage 1: the manoeuvre class. A slow car ahead in the ego's lane is stayed behind or passed on
the left (a lateral path d(s) along the route); every track whose predicted ellipse meets that path
in the station-time plane is yielded to, gone before or followed. Each combination is a homotopy
class whose speed profile along its path is a small LP solved by HiGHS; the cheapest feasible class
is the reference stage 2 tracks and is warm-started from. Formulation: docs/obp.md."""

import math
from dataclasses import dataclass
from itertools import product

import casadi as ca
import numpy as np
from scipy.sparse import csc_matrix

from advperc_ros.core.planners.obp.config import (
    CROSS_BUFFER,
    GRID_STEP,
    HEADWAY,
    MAX_CLASSES,
    PASS_CLEARANCE,
    PASS_SPEED_RATIO,
    RAMP_MAX,
    RAMP_MIN,
    RAMP_TIME,
    STANDSTILL_GAP,
    STATIC_SPEED,
    W1_ACCEL,
    W1_HEADWAY,
    W1_JERK,
    W1_LATERAL,
    Setup,
)
from advperc_ros.core.planners.obp.prediction import Obstacle


@dataclass(frozen=True)
class Reference:
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


def straight_reference(setup: Setup, s0: float, d0: float, v0: float, speed: float, label: str) -> Reference:
    """Along the route at constant acceleration from v0 to `speed` (clipped to the limits): the
    reference without stage 1 ("single-stage", tracking the route) or when no class is feasible."""
    cfg, t = setup.config, setup.stage_t
    accel = cfg.max_accel if speed >= v0 else -cfg.max_decel / 2.0
    t_reach = min((speed - v0) / accel, t[-1]) if accel else 0.0
    tt = np.minimum(t, t_reach)
    v = v0 + accel * tt
    s = s0 + v0 * tt + 0.5 * accel * tt**2 + v[-1] * (t - tt)
    zeros, d = np.zeros(setup.N + 1), np.full(setup.N + 1, d0)
    return Reference(s, v, np.diff(v) / setup.h, zeros if label == "single-stage" else d, zeros, d, zeros,
                     cost=np.inf, label=label)


class Stage1:
    """ObP's first stage: which side to pass each obstacle on and at what speed (one LP per homotopy
    class), the reference stage 2 starts from, so the NLP solves near a good local optimum."""

    def __init__(self, setup: Setup) -> None:
        self.setup = setup
        self.lp = SpeedLP(setup)

    def reference(self, s0: float, d0: float, v0: float, obstacles: list[Obstacle]) -> Reference | None:
        """Enumerate the homotopy classes, solve each one's speed LP, return the cheapest."""
        setup = self.setup
        cfg, context, t, front = setup.config, setup.context, setup.stage_t, float(setup.circle_offsets[-1])
        d_right, _ = setup.road.bounds(np.array([s0]))
        lane_half = -float(d_right[0])
        ahead = [ob for ob in obstacles if ob.s[0] + ob.a + front > s0]  # nothing to decide about the rest
        # lateral classes: pass the first n slow cars in the lane ahead (n = 0 .. passable)
        slow = sorted((ob for ob in ahead if abs(ob.d[0]) < lane_half
                       and ob.speed_along < PASS_SPEED_RATIO * cfg.target_speed),
                      key=lambda ob: (ob.s[0], ob.id))
        passable = []
        for ob in slow:
            _, d_left = setup.road.bounds(ob.s)
            if float(np.max(ob.d)) + ob.b + PASS_CLEARANCE + context.ego_width / 2.0 > float(np.min(d_left)):
                break  # the pulled-out path would leave the road
            passable.append(ob)
        v_reach = max(cfg.target_speed, v0)
        grid = np.arange(s0 - context.ego_length, s0 + v_reach * cfg.horizon + 10.0, GRID_STEP)
        t_acc = np.minimum(t, (v_reach - v0) / cfg.max_accel)
        s_max = s0 + v0 * t_acc + 0.5 * cfg.max_accel * t_acc**2 + v_reach * (t - t_acc)  # reachable station
        best: Reference | None = None
        for n_pass in range(len(passable) + 1):
            passed = passable[:n_pass]
            d_of = _lateral_path(setup, s0, d0, v0, passed)
            circles = _circle_centres(setup, grid, d_of) if ahead else []  # only an obstacle ahead reads them
            decisions, feasible = [], True
            for ob in ahead:
                if any(ob is p for p in passed):
                    continue
                lo, hi = _blocked_stations(setup, grid, circles, ob)
                blocked = np.isfinite(lo)
                if not blocked.any():
                    continue
                k1 = int(np.argmax(blocked))
                # (label, upper bound on s, lower bound on s, bound on s + HEADWAY v)
                options: list[tuple[str, np.ndarray | None, np.ndarray | None, np.ndarray | None]] = []
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
                upper, lower = np.full(setup.N + 1, np.inf), np.full(setup.N + 1, -np.inf)
                s_lead = np.full(setup.N + 1, np.inf)
                label = [path_label]
                for (ob, _), (kind, up, low, lead) in zip(decisions, combo):
                    upper = upper if up is None else np.minimum(upper, up)
                    lower = lower if low is None else np.maximum(lower, low)
                    s_lead = s_lead if lead is None else np.minimum(s_lead, lead)
                    label.append(f"{kind}:{ob.id}")
                if np.any(lower > upper):
                    continue
                sol = self.lp.solve(s0, v0, lower, upper, s_lead)
                if sol is None:
                    continue
                s, v, a, cost = sol
                d, slope = d_of(s, blend_in=False)
                cost += W1_LATERAL * float(np.sum(np.abs(d[1:]))) * setup.h
                if best is None or cost < best.cost - 1e-9:
                    d_warm, slope_warm = d_of(s)
                    best = Reference(s, v, a, d, slope, d_warm, slope_warm, cost=cost, label=" ".join(label))
        return best


def _smoothstep(u: np.ndarray) -> np.ndarray:
    u = np.clip(u, 0.0, 1.0)
    return u * u * (3.0 - 2.0 * u)


def _smoothstep_slope(u: np.ndarray) -> np.ndarray:
    return np.where((u > 0.0) & (u < 1.0), 6.0 * u * (1.0 - u), 0.0)


def _lateral_path(setup: Setup, s0: float, d0: float, v0: float, passed: list[Obstacle]):
    """The lateral path of a class: the route, pulled out to the left around every passed
    obstacle (plateau while any ego circle is alongside its ellipse, smoothstep ramps either
    side). With blend_in the ego's current offset is blended in over one ramp length."""
    ramp = float(np.clip(RAMP_TIME * v0, RAMP_MIN, RAMP_MAX))
    front = float(setup.circle_offsets[-1])
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


def _circle_centres(setup: Setup, grid: np.ndarray, d_of) -> list[tuple[np.ndarray, np.ndarray]]:
    """Where each ego circle's centre lies (x, y per grid station) with the ego's centre at the grid's stations
    on the class path `d_of`: shared by every obstacle the class decides about."""
    route = setup.context.route
    d, slope = d_of(grid)
    heading = route.heading(grid)
    yaw = heading + np.arctan(slope)
    base = route.position(grid) + d[:, None] * np.stack([-np.sin(heading), np.cos(heading)], axis=1)
    return [(base[:, 0] + off * np.cos(yaw), base[:, 1] + off * np.sin(yaw)) for off in setup.circle_offsets]


def _blocked_stations(setup: Setup, grid: np.ndarray, circles: list[tuple[np.ndarray, np.ndarray]],
                      ob: Obstacle) -> tuple[np.ndarray, np.ndarray]:
    """Per stage time, the hull [lo, hi] of the ego stations (centre) on the class path at which
    an ego circle (`_circle_centres`) lies inside the obstacle's ellipse; nan where there are none."""
    cyaw, syaw = math.cos(ob.yaw), math.sin(ob.yaw)
    inside = np.zeros((len(setup.stage_t), len(grid)), bool)
    for x, y in circles:
        qx = x[None, :] - ob.cx[:, None]
        qy = y[None, :] - ob.cy[:, None]
        lx, ly = cyaw * qx + syaw * qy, -syaw * qx + cyaw * qy
        inside |= (lx / ob.a) ** 2 + (ly / ob.b) ** 2 < 1.0
    hit = inside.any(axis=1)
    lo = np.where(hit, np.where(inside, grid[None, :], np.inf).min(axis=1), np.nan)
    hi = np.where(hit, np.where(inside, grid[None, :], -np.inf).max(axis=1), np.nan)
    return lo, hi


class SpeedLP:
    """The speed profile along a class path, an LP built once (HiGHS through CasADi's conic
    interface); each class only changes bounds. Variables: s, v (N+1 each); a, |a|, |jerk| (N each);
    headway slack (N+1)."""

    def __init__(self, setup: Setup) -> None:
        self.setup = setup
        N, h = setup.N, setup.h
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
        self._A = ca.DM(csc_matrix(np.array(rows)))
        self._solver = ca.conic("stage1", "highs", {"h": ca.Sparsity(nvar, nvar), "a": self._A.sparsity()},
                                {"highs": {"output_flag": False}, "error_on_fail": False})
        c = np.zeros(nvar)
        c[iV + 1:iV + N + 1] = -h  # maximise progress
        c[iC:iC + N] = W1_ACCEL * h
        c[iJ:iJ + N] = W1_JERK
        c[iH:iH + N + 1] = W1_HEADWAY * h
        self._cost = c
        self._layout = (iS, iV, iA, iC, iJ, iH, nvar, n_eq, n_abs)

    def solve(self, s0: float, v0: float, lower: np.ndarray, upper: np.ndarray, s_lead: np.ndarray):
        """Maximise progress, penalise |accel| and |jerk|, with the class's bounds on the station per
        stage time and s_k + HEADWAY v_k <= s_lead_k behind cars ahead in the lane, softened by a
        penalised slack so that a headway already short now (a cut-in, a merge) is restored rather
        than infeasible. Returns (s, v, a, cost) or None."""
        cfg, N, h = self.setup.config, self.setup.N, self.setup.h
        iS, iV, iA, iC, iJ, iH, nvar, n_eq, n_abs = self._layout
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
        sol = self._solver(g=self._cost, a=self._A, lba=lba, uba=uba, lbx=lbx, ubx=ubx)
        if not self._solver.stats().get("success", False):
            return None
        x = np.asarray(sol["x"]).ravel()
        cost = float(np.sum(v_cap - x[iV + 1:iV + N + 1]) * h + W1_ACCEL * h * np.sum(x[iC:iC + N])
                     + W1_JERK * np.sum(x[iJ:iJ + N]) + W1_HEADWAY * h * np.sum(x[iH:iH + N + 1]))
        return x[iS:iS + N + 1], x[iV:iV + N + 1], x[iA:iA + N], cost
