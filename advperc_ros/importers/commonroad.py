"""CommonRoad scenarios of recorded traffic -> Scenario (then a ground-truth bag).

- Lanes: every lanelet, centre vertices and mean width.
- Agents: every dynamic obstacle, all classes treated as `car` (the metrics are car-only), present
  from its initial to its final recorded time step; position is the shape's centre, velocity the
  recorded speed along the recorded orientation; height is not in CommonRoad (1.5 m).
- Ego: the planning problem's initial state, moved onto the route (its lateral offset from the
  lane centre dropped, so the path-following planner does not jump sideways at the first step).
- Route: the shortest chain of successor lanelets from the ego's lanelet to a lanelet of the goal
  region. Multi-lane roads: if the goal needs a lane change, the route stays in the ego's lane up
  to the lanelet beside the goal (the IDM planner cannot change lanes); if nothing is reachable,
  the route is the longest successor chain ahead.
- Target speed (for the generated params file): the middle of the goal's velocity interval, or
  the initial speed when the goal has none.
"""

from dataclasses import dataclass
from pathlib import Path

import networkx as nx
import numpy as np

from advperc_ros.core.boxes import BoxSequence
from advperc_ros.core.geometry import Polyline
from advperc_ros.core.scenario import EgoState, Lane, Scenario, ScenarioError

AGENT_HEIGHT = 1.5


@dataclass(frozen=True)
class ImportedScenario:
    scenario: Scenario
    target_speed: float  # m/s, for the planner
    route_note: str  # how the route was chosen


def _read(path: Path):
    try:
        from commonroad.common.file_reader import CommonRoadFileReader
    except ImportError as exc:
        raise ScenarioError(f"{path}: reading CommonRoad needs commonroad-io (pip install '.[commonroad]')") from exc
    if not path.is_file():
        raise ScenarioError(f"{path}: no such CommonRoad file")
    try:
        return CommonRoadFileReader(str(path)).open()
    except Exception as exc:  # the reader raises many types for malformed XML
        raise ScenarioError(f"{path}: not a readable CommonRoad scenario: {exc}".replace("\n", " ")) from exc


def _agents(cr_scenario, num_frames: int) -> BoxSequence:
    obstacles = sorted(cr_scenario.dynamic_obstacles, key=lambda o: o.obstacle_id)
    agents = BoxSequence.empty(num_frames, len(obstacles))
    for j, obstacle in enumerate(obstacles):
        states = [obstacle.initial_state, *obstacle.prediction.trajectory.state_list]
        agents.ids[:, j] = obstacle.obstacle_id
        shape = obstacle.obstacle_shape
        agents.length[:, j], agents.width[:, j], agents.height[:, j] = shape.length, shape.width, AGENT_HEIGHT
        for state in states:
            k = int(state.time_step)
            if not 0 <= k < num_frames:
                continue
            speed = float(getattr(state, "velocity", 0.0) or 0.0)
            yaw = float(state.orientation)
            agents.valid[k, j] = True
            agents.x[k, j], agents.y[k, j] = state.position
            agents.yaw[k, j] = yaw
            agents.vx[k, j], agents.vy[k, j] = speed * np.cos(yaw), speed * np.sin(yaw)
    return agents


def _goal_centre(goal) -> np.ndarray | None:
    for state in goal.state_list:
        position = getattr(state, "position", None)
        if position is not None:
            centre = getattr(position, "center", None)
            if centre is None and getattr(position, "shapes", None):
                centre = position.shapes[0].center
            if centre is not None:  # an array, or a shapely Point for some shapes
                return np.array([centre.x, centre.y]) if hasattr(centre, "x") else np.asarray(centre, dtype=float)
    return None


def _route(network, start_xy: np.ndarray, goal) -> tuple[list[int], str]:
    graph = nx.DiGraph()
    for lanelet in network.lanelets:
        graph.add_node(lanelet.lanelet_id)
        for successor in lanelet.successor:
            graph.add_edge(lanelet.lanelet_id, successor)
    found = network.find_lanelet_by_position([start_xy])[0]
    if not found:
        raise ScenarioError("the ego's start is on no lanelet")
    start = found[0]
    goal_lanelets: set[int] = set()
    if goal.lanelets_of_goal_position:
        goal_lanelets = {i for ids in goal.lanelets_of_goal_position.values() for i in ids}
    centre = _goal_centre(goal)
    if centre is not None:
        goal_lanelets |= set(network.find_lanelet_by_position([centre])[0])
    paths = [nx.shortest_path(graph, start, g) for g in goal_lanelets if nx.has_path(graph, start, g)]
    if paths:
        return min(paths, key=len), "shortest successor chain to the goal"
    beside = {
        n
        for g in goal_lanelets
        for n in (network.find_lanelet_by_id(g).adj_left, network.find_lanelet_by_id(g).adj_right)
        if n is not None
    }
    paths = [nx.shortest_path(graph, start, g) for g in beside if nx.has_path(graph, start, g)]
    if paths:
        return min(paths, key=len), "goal needs a lane change: route stays in the ego's lane beside the goal"
    longest = max(nx.single_source_shortest_path(graph, start).values(), key=len)
    return longest, "goal not reachable along successors: route is the longest successor chain ahead"


def import_commonroad(path: str | Path) -> ImportedScenario:
    path = Path(path)
    cr_scenario, problems = _read(path)
    if not problems.planning_problem_dict:
        raise ScenarioError(f"{path}: field 'planningProblem' is missing (needed for the ego's start)")
    problem = problems.planning_problem_dict[min(problems.planning_problem_dict)]
    network = cr_scenario.lanelet_network
    dt = float(cr_scenario.dt)
    last = max((o.prediction.trajectory.final_state.time_step for o in cr_scenario.dynamic_obstacles), default=0)
    num_frames = int(last) + 1
    lanes = tuple(
        Lane(
            id=str(lanelet.lanelet_id),
            centerline=Polyline(lanelet.center_vertices),
            width=float(np.mean(np.linalg.norm(lanelet.left_vertices - lanelet.right_vertices, axis=1))),
        )
        for lanelet in network.lanelets
    )
    initial = problem.initial_state
    start_xy = np.asarray(initial.position, dtype=float)
    try:
        chain, note = _route(network, start_xy, problem.goal)
    except ScenarioError as exc:
        raise ScenarioError(f"{path}: field 'planningProblem.initialState': {exc}") from exc
    route = Polyline(np.concatenate([network.find_lanelet_by_id(i).center_vertices for i in chain]))
    s0, _ = route.project(start_xy)
    on_route = route.position(s0)
    speed = float(getattr(initial, "velocity", 0.0) or 0.0)
    ego = EgoState(x=float(on_route[0]), y=float(on_route[1]), yaw=float(route.heading(s0)), v=speed)
    target = speed
    for state in problem.goal.state_list:
        velocity = getattr(state, "velocity", None)
        if velocity is not None and hasattr(velocity, "start"):
            target = 0.5 * (float(velocity.start) + float(velocity.end))
    scenario = Scenario(
        name=str(cr_scenario.scenario_id),
        stamps_ns=np.arange(num_frames, dtype=np.int64) * int(round(dt * 1e9)),
        agents=_agents(cr_scenario, num_frames),
        lanes=lanes,
        route=route,
        ego_start=ego,
    )
    scenario.validate(str(path))
    return ImportedScenario(scenario=scenario, target_speed=max(target, 1.0), route_note=note)
