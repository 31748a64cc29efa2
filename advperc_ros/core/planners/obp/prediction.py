"""What the planner expects of the tracks: constant-velocity predictions at the stage times,
cleaned of the tracker's velocity noise, each with the ellipse both stages keep the ego's circles
out of. Tracks that cannot come near the ego within the horizon are pruned."""

import math
from dataclasses import dataclass

import numpy as np

from advperc_ros.core.geometry import Polyline
from advperc_ros.core.planners.obp.config import ELLIPSE_STRETCH, LANE_SNAP_ANGLE, STATIC_SPEED, Setup


@dataclass(frozen=True)
class Obstacle:
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


def track_velocities(tracks: dict[str, np.ndarray], setup: Setup) -> tuple[np.ndarray, np.ndarray]:
    """Track velocities for the constant-velocity prediction, cleaned of the tracker's noise:
    slower than STATIC_SPEED is stationary; a track inside a lane and moving within
    LANE_SNAP_ANGLE of the lane's direction keeps only its velocity along the lane (of several such
    lanes, the one nearest the track's centre, the first of the lanes when two are as near). Every
    track is projected onto every lane in one pass (`Setup.lanes`): one lane at a time, a recording's
    hundred lanes had cost a third of an ObP rollout."""
    vx, vy = np.array(tracks["vx"], float), np.array(tracks["vy"], float)
    speed = np.hypot(vx, vy)
    slow = speed < STATIC_SPEED
    vx[slow], vy[slow] = 0.0, 0.0
    if slow.all() or len(setup.lanes) == 0:
        return vx, vy
    xy = np.stack([np.asarray(tracks["x"], float), np.asarray(tracks["y"], float)], axis=1)
    stations, lateral = setup.lanes.project_all(xy)  # (L, M)
    offset = np.abs(lateral)
    lane, track = np.nonzero(~slow & (offset < setup.lane_half_widths[:, None]))  # inside a lane, moving
    heading = np.arctan2(*setup.lanes.directions(lane, stations[lane, track]).T[::-1])  # Polyline.heading's
    tx, ty = np.cos(heading), np.sin(heading)
    along = vx[track] * tx + vy[track] * ty
    its_way = along > math.cos(LANE_SNAP_ANGLE) * speed[track]
    nearest = np.full(offset.shape, np.inf)
    nearest[lane[its_way], track[its_way]] = offset[lane[its_way], track[its_way]]
    chosen = np.argmin(nearest, axis=0)  # per track, the first of the nearest lanes it fits
    out_x, out_y = vx.copy(), vy.copy()
    pick = its_way & (lane == chosen[track])
    out_x[track[pick]], out_y[track[pick]] = along[pick] * tx[pick], along[pick] * ty[pick]
    return out_x, out_y


def _stations(route: Polyline, cx: np.ndarray, cy: np.ndarray, moving: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """`route.project` of the predicted centres (M, N+1), a standing track's once: its centre stays put at every
    stage time, and a point's projection does not depend on the others projected with it."""
    s, d = np.empty(cx.shape), np.empty(cx.shape)
    if moving.any():
        s[moving], d[moving] = route.project(np.stack([cx[moving], cy[moving]], axis=-1))
    if not moving.all():
        standing_s, standing_d = route.project(np.stack([cx[~moving, 0], cy[~moving, 0]], axis=-1))
        s[~moving], d[~moving] = standing_s[:, None], standing_d[:, None]
    return s, d


def predict(setup: Setup, s0: float, tracks: dict[str, np.ndarray]) -> list[Obstacle]:
    """Constant-velocity predictions of the tracks that can come near the ego (at station s0)
    within the horizon. Tracks behind the ego that are not closing in are pruned."""
    cfg, context, t = setup.config, setup.context, setup.stage_t
    if len(tracks["x"]) == 0:
        return []
    route = context.route
    vx, vy = track_velocities(tracks, setup)
    cx = np.asarray(tracks["x"], float)[:, None] + vx[:, None] * t
    cy = np.asarray(tracks["y"], float)[:, None] + vy[:, None] * t
    s, d = _stations(route, cx, cy, (vx != 0.0) | (vy != 0.0))
    heading0 = route.heading(s[:, 0])
    along = vx * np.cos(heading0) + vy * np.sin(heading0)
    a, b = ellipse_axes(np.asarray(tracks["length"]) / 2.0 + cfg.safety_margin,
                        np.asarray(tracks["width"]) / 2.0 + cfg.safety_margin, setup.circle_radius)
    v_reach = max(cfg.target_speed, 1.0)
    d_right, d_left = setup.road.bounds(np.array([s0]))
    out = []
    for i in range(len(cx)):
        ext = a[i] + context.ego_length
        near = ((s[i] > s0 - ext) & (s[i] < s0 + v_reach * t + ext)
                & (d[i] > d_right[0] - b[i] - 1.0) & (d[i] < d_left[0] + b[i] + 1.0))
        behind_not_closing = s[i, 0] + ext < s0 and along[i] <= cfg.target_speed
        if near.any() and not behind_not_closing:
            out.append(Obstacle(id=int(tracks["ids"][i]), cx=cx[i], cy=cy[i], yaw=float(tracks["yaw"][i]),
                                a=float(a[i]), b=float(b[i]), s=s[i], d=d[i], speed_along=float(along[i])))
    return out
