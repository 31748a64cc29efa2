"""Build a Scenario from a hand-written YAML description (lanes, agents' motion, ego start).

Agents move along a lane centreline with a piecewise-linear speed profile and an optional lateral
offset profile (to swerve around an obstacle). Everything is sampled on the frame grid, so the
scenario is exactly what a ground-truth bag will replay.
"""

from pathlib import Path
from typing import Any

import numpy as np
import yaml

from advperc_ros.core.boxes import BoxSequence
from advperc_ros.core.geometry import Polyline
from advperc_ros.core.inputs import read_input_text
from advperc_ros.core.scenario import EgoState, Lane, Scenario
from advperc_ros.exceptions import ScenarioError


def _knots(value: Any, source: str, field: str) -> np.ndarray:
    """A scalar or a list of [x, y] knots as an (K, 2) array sorted by x."""
    if isinstance(value, (int, float)):
        return np.array([[0.0, float(value)]])
    arr = np.asarray(value, dtype=float)
    if arr.ndim != 2 or arr.shape[1] != 2 or arr.shape[0] == 0 or np.any(np.diff(arr[:, 0]) <= 0):
        raise ScenarioError(f"{source}: field '{field}' must be a number or a list of increasing [x, y] knots")
    return arr


def _linear(knots: np.ndarray, x: np.ndarray) -> np.ndarray:
    return np.interp(x, knots[:, 0], knots[:, 1])


def _smooth(knots: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Piecewise interpolation with a smoothstep between knots, so swerves have continuous heading."""
    if knots.shape[0] == 1:
        return np.full_like(x, knots[0, 1])
    i = np.clip(np.searchsorted(knots[:, 0], x, side="right") - 1, 0, knots.shape[0] - 2)
    x0, x1 = knots[i, 0], knots[i + 1, 0]
    u = np.clip((x - x0) / (x1 - x0), 0.0, 1.0)
    u = u * u * (3.0 - 2.0 * u)
    return knots[i, 1] + (knots[i + 1, 1] - knots[i, 1]) * u


def connector(incoming: Polyline, outgoing: Polyline, points: int = 25) -> Polyline:
    """A junction connector: the cubic Hermite curve from the end of one lane to the start of the
    next, tangent to both, with tangent lengths equal to the gap (a near-circular quarter turn)."""
    p0, p1 = incoming.points[-1], outgoing.points[0]
    h0, h1 = incoming.heading(incoming.length), outgoing.heading(0.0)
    scale = np.linalg.norm(p1 - p0)
    m0 = scale * np.array([np.cos(h0), np.sin(h0)])
    m1 = scale * np.array([np.cos(h1), np.sin(h1)])
    u = np.linspace(0.0, 1.0, points)[:, None]
    curve = ((2 * u**3 - 3 * u**2 + 1) * p0 + (u**3 - 2 * u**2 + u) * m0
             + (-2 * u**3 + 3 * u**2) * p1 + (u**3 - u**2) * m1)
    return Polyline(curve)


def _require(mapping: dict, key: str, source: str, where: str) -> Any:
    if key not in mapping:
        raise ScenarioError(f"{source}: field '{where}{key}' is missing")
    return mapping[key]


def build_scenario(spec: dict, source: str = "<scenario>") -> Scenario:
    """Sample a scenario description on its frame grid."""
    dt = float(_require(spec, "dt", source, ""))
    duration = float(_require(spec, "duration", source, ""))
    num_frames = int(round(duration / dt)) + 1
    times = np.arange(num_frames) * dt
    dt_ns = int(round(dt * 1e9))
    stamps_ns = np.arange(num_frames, dtype=np.int64) * dt_ns

    lanes: dict[str, Lane] = {}
    for i, lane in enumerate(_require(spec, "lanes", source, "")):
        lane_id = str(_require(lane, "id", source, f"lanes[{i}]."))
        if "connect" in lane:
            ends = lane["connect"]
            if not (isinstance(ends, list) and len(ends) == 2 and all(str(e) in lanes for e in ends)):
                raise ScenarioError(f"{source}: field 'lanes[{i}].connect' must name two lanes listed before it")
            start, end = lanes[str(ends[0])], lanes[str(ends[1])]
            centerline = connector(start.centerline, end.centerline)
            width = float(lane.get("width", min(start.width, end.width)))
        else:
            centerline = Polyline(np.asarray(_require(lane, "centerline", source, f"lanes[{i}]."), dtype=float))
            width = float(lane.get("width", 3.5))
        lanes[lane_id] = Lane(id=lane_id, centerline=centerline, width=width)

    def lane_of(name: str, field: str) -> Lane:
        if name not in lanes:
            raise ScenarioError(f"{source}: field '{field}' names unknown lane '{name}'")
        return lanes[name]

    ego = _require(spec, "ego", source, "")
    route_lanes = [lane_of(str(name), "ego.route") for name in _require(ego, "route", source, "ego.")]
    route = Polyline(np.concatenate([lane.centerline.points for lane in route_lanes]))
    start_s = float(_require(ego, "start_s", source, "ego."))
    start_xy = route.position(start_s)
    ego_start = EgoState(
        x=float(start_xy[0]), y=float(start_xy[1]), yaw=float(route.heading(start_s)), v=float(ego.get("speed", 0.0))
    )

    agent_specs = spec.get("agents", [])
    agents = BoxSequence.empty(num_frames, len(agent_specs))
    for j, agent in enumerate(agent_specs):
        where = f"agents[{j}]."
        agents.ids[:, j] = int(_require(agent, "id", source, where))
        lane = lane_of(str(_require(agent, "lane", source, where)), f"{where}lane")
        speed = _knots(agent.get("speed", 0.0), source, f"{where}speed")
        lateral = _knots(agent.get("lateral", 0.0), source, f"{where}lateral")
        v = np.maximum(_linear(speed, times), 0.0)
        travelled = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * dt)])
        s = float(_require(agent, "start_s", source, where)) + travelled
        offset = _smooth(lateral, travelled)
        heading = lane.centerline.heading(s)
        xy = lane.centerline.position(s) + offset[:, None] * np.stack([-np.sin(heading), np.cos(heading)], axis=1)
        vel = np.gradient(xy, dt, axis=0)
        moving = np.linalg.norm(vel, axis=1) > 0.05
        agents.x[:, j], agents.y[:, j] = xy[:, 0], xy[:, 1]
        agents.yaw[:, j] = np.where(moving, np.arctan2(vel[:, 1], vel[:, 0]), heading)
        agents.vx[:, j], agents.vy[:, j] = vel[:, 0], vel[:, 1]
        agents.length[:, j], agents.width[:, j], agents.height[:, j] = agent.get("size", [4.5, 1.9, 1.6])
        appear = float(agent.get("appear", 0.0))
        disappear = agent.get("disappear")
        last = np.inf if disappear is None else float(disappear)
        agents.valid[:, j] = (times >= appear - 1e-9) & (times <= last + 1e-9)

    scenario = Scenario(
        name=str(_require(spec, "name", source, "")),
        stamps_ns=stamps_ns,
        agents=agents,
        lanes=tuple(lanes.values()),
        route=route,
        ego_start=ego_start,
    )
    scenario.validate(source)
    return scenario


def load_scenario_spec(path: str | Path) -> Scenario:
    """The Scenario a YAML scenario description file describes (`advperc make-bag`); one ScenarioError
    line naming the file for whatever is wrong."""
    path = Path(path)
    try:
        spec = yaml.safe_load(read_input_text(path))
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
        raise ScenarioError(f"{path}: cannot read scenario description: {exc}") from exc
    if not isinstance(spec, dict):
        raise ScenarioError(f"{path}: a scenario description must be a mapping")
    return build_scenario(spec, str(path))
