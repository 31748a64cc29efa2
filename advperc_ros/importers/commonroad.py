"""CommonRoad scenarios of recorded traffic -> Scenario (then a ground-truth bag).

- Lanes: every lanelet, centre vertices and mean width.
- Agents: every dynamic obstacle, all classes treated as `car` (the metrics are car-only), present
  from its initial to its final recorded time step (at its initial step only if it has no
  trajectory); position is the shape's centre, velocity the recorded speed along the recorded
  orientation; height is not in CommonRoad (1.5 m).
- Ego: the planning problem's initial state, moved onto the route (its lateral offset from the
  lane centre dropped, so the path-following planner does not jump sideways at the first step).
- Route: the shortest chain of successor lanelets from the ego's lanelet to a lanelet of the goal
  region. Multi-lane roads: if the goal needs a lane change, the route stays in the ego's lane up
  to the lanelet beside the goal (the IDM planner cannot change lanes); if nothing is reachable,
  the route is the longest successor chain ahead. Where the chain's centre line turns tighter than
  `ROUTE_MIN_RADIUS` (the lanelets of some junctions turn at 1.7-4.2 m radii, which no car can drive:
  ObP's NLP failed most solves there, every one with the cars hidden, and its ego never left), its
  corners are rounded to that radius (`geometry.round_corners`); the lanes stay as in the map.
- Target speed (for the generated params file): the top of the goal's velocity interval, the
  fastest speed at which the ego still meets its goal (an ego given the middle drives at the
  recorded car's own speed and never closes on the traffic ahead, so no hidden vehicle matters);
  with no interval, the operating speed of the route's traffic (see `operating_speed`), else the
  initial speed.
- Refused with a ScenarioError naming the file and the field, rather than failing later: numbers
  that are not finite, shapes other than rectangles, predictions that are not trajectories, two
  states at one time step, references to lanelets that do not exist, degenerate lanelets, and
  orientations beyond +-1000 rad (commonroad-io itself would never finish reading those).
- `shift_traffic` writes a recording with its traffic of another moment: held-out recordings for
  checking the commands on data no rule here was written on (benchmarks/shifted_recordings.py).
"""

import warnings
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import networkx as nx
import numpy as np

from advperc_ros.core.boxes import BoxSequence
from advperc_ros.core.geometry import Polyline, round_corners
from advperc_ros.core.rules.verdict import AT_FAULT_RULE
from advperc_ros.core.scenario import EgoState, Lane, Scenario
from advperc_ros.exceptions import ScenarioError

AGENT_HEIGHT = 1.5
MAX_ANGLE = 1000.0  # rad: recorded orientations are within a few turns; see _check_orientations
ROUTE_MIN_RADIUS = 5.0  # m: a passenger car's tightest turn (ObP's 2.7 m wheelbase at its 0.5 rad steering limit: 4.95 m)
MAX_ROUTE_LENGTH = 20_000.0  # m: past it a lanelet's vertex is garbage (and rounding its corners would take minutes)
MAX_FRAMES = 10_000  # time steps of a recording: CommonRoad's run for seconds; a bogus step would only fill memory


@dataclass(frozen=True)
class ImportedScenario:
    scenario: Scenario
    target_speed: float  # m/s, for the planner
    route_note: str  # how the route was chosen

    def params(self, bag: str, planner: str) -> dict:
        """The params document of an attack on this recording's bag with `planner`, as
        import-commonroad writes it: the goal's target speed, and only at-fault collisions counted
        (recorded agents do not react to the ego: being rear-ended is theirs, not the ego's fault)."""
        return {"orchestrator": {"ros__parameters": {
            "bag": bag,
            "planner": planner,
            "planner_params": {"target_speed": round(self.target_speed, 3)},
            "objective": "nds_t",
            "seed": 0,
            "rule": {"name": AT_FAULT_RULE},
        }}}


def _read(path: Path):
    try:
        from commonroad.common.file_reader import CommonRoadFileReader
    except ImportError as exc:
        raise ScenarioError(f"{path}: reading CommonRoad needs commonroad-io (pip install '.[commonroad]')") from exc
    if not path.is_file():
        raise ScenarioError(f"{path}: no such CommonRoad file")
    _check_orientations(path)
    try:
        return CommonRoadFileReader(str(path)).open()
    except Exception as exc:  # the reader raises many types for malformed XML
        raise ScenarioError(f"{path}: not a readable CommonRoad scenario: {exc}".replace("\n", " ")) from exc


def _check_orientations(path: Path) -> None:
    """Refuse an XML file whose orientations commonroad-io cannot read: it brings every angle into
    [-2 pi, 2 pi] by subtracting 2 pi in a loop, which never ends for inf or 1e308 (and takes
    minutes for 1e10). A file that does not parse is left to the reader to refuse."""
    if path.suffix.lower() != ".xml":
        return
    try:
        root = ET.parse(path).getroot()
    except (SyntaxError, LookupError, ValueError):  # ParseError, an unknown encoding, bytes it cannot decode
        return
    for owner in root:  # lanelets, obstacles, planning problems: what the error can name
        for orientation in owner.iter("orientation"):
            for element in orientation.iter():
                if element.text is None:
                    continue  # no text: the reader's to refuse
                try:
                    angle = float(element.text)
                except ValueError:
                    continue  # not a number: the reader's to refuse
                if not abs(angle) <= MAX_ANGLE:
                    raise ScenarioError(f"{path}: field '{owner.tag} {owner.get('id')}.orientation' must be within "
                                        f"+-{MAX_ANGLE:g} rad, not {element.text.strip()[:30]}")


def _finite(value, field: str, size: int | None = None) -> np.ndarray:
    """A number (or `size` of them) of the recording as floats; a ScenarioError naming `field`
    unless all are finite (NaN or inf in a recording would only surface deep in a rollout)."""
    try:
        values = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        values = np.array([np.nan])
    if values.shape != (() if size is None else (size,)) or not np.all(np.isfinite(values)):
        raise ScenarioError(f"field '{field}' must be {'a finite number' if size is None else f'{size} finite numbers'}")
    return values


def _states(obstacle) -> dict[int, object]:
    """A dynamic obstacle's recorded states by time step: its initial state, then its trajectory (an
    obstacle without a prediction is known at its initial step only). Every state must be exact."""
    name = f"dynamicObstacle {obstacle.obstacle_id}"
    prediction = obstacle.prediction
    if prediction is not None and getattr(prediction, "trajectory", None) is None:
        raise ScenarioError(f"field '{name}.prediction' is not a recorded trajectory")
    states: dict[int, object] = {}
    for state in [obstacle.initial_state, *(prediction.trajectory.state_list if prediction is not None else ())]:
        k = state.time_step
        if not isinstance(k, (int, np.integer)) or not 0 <= k < MAX_FRAMES:
            raise ScenarioError(f"field '{name}.time_step' must be a whole step in [0, {MAX_FRAMES}), not {k!r:.30}")
        if int(k) in states:
            raise ScenarioError(f"field '{name}' has two states at time step {k}")
        states[int(k)] = state
    return states


def _agents(cr_scenario, num_frames: int, states: dict[int, dict[int, object]]) -> BoxSequence:
    obstacles = sorted(cr_scenario.dynamic_obstacles, key=lambda o: o.obstacle_id)
    agents = BoxSequence.empty(num_frames, len(obstacles))
    for j, obstacle in enumerate(obstacles):
        name = f"dynamicObstacle {obstacle.obstacle_id}"
        if not np.iinfo(np.int64).min <= obstacle.obstacle_id <= np.iinfo(np.int64).max:
            raise ScenarioError(f"field '{name}' has an id beyond 64 bits")
        agents.ids[:, j] = obstacle.obstacle_id
        shape = obstacle.obstacle_shape
        if not (hasattr(shape, "length") and hasattr(shape, "width")):
            raise ScenarioError(f"field '{name}.shape' must be a rectangle, not {type(shape).__name__}")
        agents.length[:, j], agents.width[:, j], agents.height[:, j] = shape.length, shape.width, AGENT_HEIGHT
        for k, state in states[obstacle.obstacle_id].items():
            speed = _speed(state, f"{name}.velocity")
            yaw = float(_finite(getattr(state, "orientation", None), f"{name}.orientation"))
            agents.valid[k, j] = True
            agents.x[k, j], agents.y[k, j] = _finite(getattr(state, "position", None), f"{name}.position", 2)
            agents.yaw[k, j] = yaw
            agents.vx[k, j], agents.vy[k, j] = speed * np.cos(yaw), speed * np.sin(yaw)
    return agents


def _speed(state, field: str) -> float:
    """A state's recorded speed; 0 for state types that have none."""
    velocity = getattr(state, "velocity", None)
    return 0.0 if velocity is None else float(_finite(velocity, field))


def _goal_centre(goal) -> np.ndarray | None:
    for state in goal.state_list:
        position = getattr(state, "position", None)
        if position is not None:
            centre = getattr(position, "center", None)
            if centre is None and getattr(position, "shapes", None):
                centre = position.shapes[0].center
            if centre is not None:  # an array, or a shapely Point (maybe empty: no .x) for some shapes
                xy = np.asarray(centre.coords, dtype=float).ravel() if hasattr(centre, "coords") else centre
                return _finite(xy, "planningProblem.goalState.position", 2)
    return None


def _lane(lanelet) -> Lane:
    """A lanelet as a lane: its centre vertices, the mean distance between its bounds as width."""
    name = f"lanelet {lanelet.lanelet_id}"
    left, right = np.asarray(lanelet.left_vertices, dtype=float), np.asarray(lanelet.right_vertices, dtype=float)
    if left.shape != right.shape or not (np.all(np.isfinite(left)) and np.all(np.isfinite(right))):
        raise ScenarioError(f"field '{name}': leftBound and rightBound must be finite points, as many of each")
    try:
        centerline = Polyline(lanelet.center_vertices)
    except ValueError:
        raise ScenarioError(f"field '{name}': its centre needs at least two distinct points") from None
    return Lane(id=str(lanelet.lanelet_id), centerline=centerline,
                width=float(np.mean(np.linalg.norm(left - right, axis=1))))


def _route(network, start_xy: np.ndarray, goal) -> tuple[list[int], str]:
    by_id = {lanelet.lanelet_id: lanelet for lanelet in network.lanelets}
    graph = nx.DiGraph()
    for lanelet in network.lanelets:
        graph.add_node(lanelet.lanelet_id)
    for lanelet in network.lanelets:
        for other in (*lanelet.successor, lanelet.adj_left, lanelet.adj_right):
            if other is not None and other not in graph:
                raise ScenarioError(f"field 'lanelet {lanelet.lanelet_id}' refers to lanelet {other}, which does not exist")
        for successor in lanelet.successor:
            graph.add_edge(lanelet.lanelet_id, successor)
    found = network.find_lanelet_by_position([start_xy])[0]
    if not found:
        raise ScenarioError("field 'planningProblem.initialState': the ego's start is on no lanelet")
    start = found[0]
    goal_lanelets: set[int] = set()
    if goal.lanelets_of_goal_position:
        goal_lanelets = {i for ids in goal.lanelets_of_goal_position.values() for i in ids}
    missing = sorted(goal_lanelets - set(graph))
    if missing:
        raise ScenarioError(f"field 'planningProblem.goalState' names lanelet {missing[0]}, which does not exist")
    centre = _goal_centre(goal)
    if centre is not None:
        goal_lanelets |= set(network.find_lanelet_by_position([centre])[0])
    paths = [nx.shortest_path(graph, start, g) for g in goal_lanelets if nx.has_path(graph, start, g)]
    if paths:
        return min(paths, key=len), "shortest successor chain to the goal"
    beside = {
        n
        for g in goal_lanelets
        for n in (by_id[g].adj_left, by_id[g].adj_right)
        if n is not None
    }
    paths = [nx.shortest_path(graph, start, g) for g in beside if nx.has_path(graph, start, g)]
    if paths:
        return min(paths, key=len), "goal needs a lane change: route stays in the ego's lane beside the goal"
    longest = max(nx.single_source_shortest_path(graph, start).values(), key=len)
    return longest, "goal not reachable along successors: route is the longest successor chain ahead"


OPERATING_PERCENTILE = 85.0  # traffic engineering's operating speed, the basis of speed limits
ON_ROUTE = 1.75  # m from the route's centre line, half a lane: a vehicle driving in the route's lane
ALONG_ROUTE = np.pi / 4  # rad between a vehicle's heading and the route's: driving along it, not across


def operating_speed(route: Polyline, agents: BoxSequence) -> float | None:
    """The 85th percentile of the recorded speeds of vehicles in the route's lane and driving along
    it, over the whole recording; None when no vehicle ever is."""
    frames, slots = np.nonzero(agents.valid)
    xy = np.stack([agents.x[frames, slots], agents.y[frames, slots]], axis=1)
    s, lateral = route.project(xy)
    heading = np.angle(np.exp(1j * (agents.yaw[frames, slots] - route.heading(s))))
    along = (np.abs(lateral) < ON_ROUTE) & (np.abs(heading) < ALONG_ROUTE)
    if not along.any():
        return None
    speeds = np.hypot(agents.vx[frames, slots], agents.vy[frames, slots])[along]
    return float(np.percentile(speeds, OPERATING_PERCENTILE))


def _target_speed(goal, route: Polyline, agents: BoxSequence, initial_speed: float) -> float:
    """The planner's target speed (module docstring): the goal interval's top, else the route
    traffic's operating speed, else the initial speed; at least 1 m/s (a target of 0 only brakes)."""
    for state in goal.state_list:
        velocity = getattr(state, "velocity", None)
        if velocity is not None and hasattr(velocity, "end"):
            return max(float(_finite([velocity.start, velocity.end], "planningProblem.goalState.velocity", 2)[1]), 1.0)
    traffic = operating_speed(route, agents)
    return max(initial_speed if traffic is None else traffic, 1.0)


def import_commonroad(path: str | Path) -> ImportedScenario:
    """A CommonRoad recording as a validated Scenario; a ScenarioError naming the file and the
    field for anything that cannot be used (one line)."""
    path = Path(path)
    cr_scenario, problems = _read(path)
    try:
        imported = _convert(cr_scenario, problems)
    except ScenarioError as exc:
        raise ScenarioError(f"{path}: {exc}") from None
    imported.scenario.validate(str(path))
    return imported


def _check_unique_ids(cr_scenario, problems) -> None:
    """CommonRoad ids are unique across a scenario; the reader does not check it. An obstacle with the
    planning problem's id would be an agent and the ego at once to whoever reads ids, and a lanelet's
    would make a route through an obstacle's number."""
    owners: dict[int, str] = {}
    named = ([("lanelet", lanelet.lanelet_id) for lanelet in cr_scenario.lanelet_network.lanelets]
             + [("planningProblem", problem_id) for problem_id in problems.planning_problem_dict]
             + [("dynamicObstacle", o.obstacle_id) for o in cr_scenario.dynamic_obstacles]
             + [("staticObstacle", o.obstacle_id) for o in cr_scenario.static_obstacles])
    for kind, element_id in named:
        if element_id in owners:
            raise ScenarioError(f"field '{kind} {element_id}' has the id of {owners[element_id]}: "
                                "ids must be unique across a CommonRoad scenario")
        owners[element_id] = f"{kind} {element_id}"


def _convert(cr_scenario, problems) -> ImportedScenario:
    if not problems.planning_problem_dict:
        raise ScenarioError("field 'planningProblem' is missing (needed for the ego's start)")
    _check_unique_ids(cr_scenario, problems)
    problem = problems.planning_problem_dict[min(problems.planning_problem_dict)]
    network = cr_scenario.lanelet_network
    dt = float(_finite(cr_scenario.dt, "timeStepSize"))
    if not 1e-9 <= dt <= 3600.0:  # stamps are int64 nanoseconds
        raise ScenarioError(f"field 'timeStepSize' must be between 1 ns and 1 h, not {dt}")
    states = {o.obstacle_id: _states(o) for o in cr_scenario.dynamic_obstacles}
    num_frames = max((k for steps in states.values() for k in steps), default=0) + 1
    lanes = tuple(_lane(lanelet) for lanelet in network.lanelets)
    lanes_by_id = {lane.id: lane for lane in lanes}
    initial = problem.initial_state
    start_xy = _finite(getattr(initial, "position", None), "planningProblem.initialState.position", 2)
    chain, note = _route(network, start_xy, problem.goal)
    centre_line = Polyline(np.concatenate([lanes_by_id[str(i)].centerline.points for i in chain]))
    if centre_line.length > MAX_ROUTE_LENGTH:
        raise ScenarioError(f"field 'lanelet {chain[0]}': the route along its successors is {centre_line.length:.3g} m "
                            f"long, beyond {MAX_ROUTE_LENGTH:g} m (a recording's road is a few hundred)")
    try:
        route = round_corners(centre_line, ROUTE_MIN_RADIUS)
    except ValueError:  # a turn back on itself: no curve of that radius stays near it
        route = centre_line
        note += f"; it turns tighter than a {ROUTE_MIN_RADIUS:g} m radius where no rounding can help (as in the map)"
    if route is not centre_line:
        moved = float(np.max(np.abs(centre_line.project(route.points)[1])))
        note += f"; its corners rounded to a {ROUTE_MIN_RADIUS:g} m radius, at most {moved:.2f} m off the lanes' centre line"
    s0, _ = route.project(start_xy)
    on_route = route.position(s0)
    speed = _speed(initial, "planningProblem.initialState.velocity")
    ego = EgoState(x=float(on_route[0]), y=float(on_route[1]), yaw=float(route.heading(s0)), v=speed)
    agents = _agents(cr_scenario, num_frames, states)
    target = _target_speed(problem.goal, route, agents, speed)
    scenario = Scenario(
        name=str(cr_scenario.scenario_id),
        stamps_ns=np.arange(num_frames, dtype=np.int64) * int(round(dt * 1e9)),
        agents=agents,
        lanes=lanes,
        route=route,
        ego_start=ego,
    )
    return ImportedScenario(scenario=scenario, target_speed=target, route_note=note)


def shift_traffic(source: Path, target: Path, seconds: float) -> int:
    """Write the recording `source` to `target` with every vehicle `seconds` earlier (the ego meets
    the traffic that passed its start that much after the recorded car it replaces did): vehicles
    gone by then dropped, the others starting from their first state at or after that moment; the
    map, ego and goal the file's own. The same road at another moment, a recording no rule of the
    tool was written or measured on. Returns the vehicles kept."""
    from commonroad.common.file_reader import CommonRoadFileReader
    from commonroad.common.file_writer import CommonRoadFileWriter, OverwriteExistingFile
    from commonroad.common.util import FileFormat
    from commonroad.prediction.prediction import TrajectoryPrediction
    from commonroad.scenario.obstacle import DynamicObstacle
    from commonroad.scenario.state import InitialState
    from commonroad.scenario.trajectory import Trajectory

    scenario, problems = CommonRoadFileReader(str(source)).open()
    steps = round(seconds / scenario.dt)
    moved = []
    for obstacle in scenario.dynamic_obstacles:
        states = [obstacle.initial_state]
        if isinstance(obstacle.prediction, TrajectoryPrediction):
            states += obstacle.prediction.trajectory.state_list
        states = [s for s in states if s.time_step >= steps]
        if not states:  # gone before the new start
            continue
        for state in states:
            state.time_step -= steps
        first = states[0]
        initial = InitialState(time_step=first.time_step, position=first.position, orientation=first.orientation,
                               velocity=first.velocity, acceleration=getattr(first, "acceleration", 0.0) or 0.0,
                               yaw_rate=0.0, slip_angle=0.0)
        prediction = (TrajectoryPrediction(Trajectory(first.time_step + 1, states[1:]), obstacle.obstacle_shape)
                      if len(states) > 1 else None)
        moved.append(DynamicObstacle(obstacle.obstacle_id, obstacle.obstacle_type, obstacle.obstacle_shape, initial,
                                     prediction))
    for obstacle in list(scenario.dynamic_obstacles):
        scenario.remove_obstacle(obstacle)
    scenario.add_objects(moved)
    writer = CommonRoadFileWriter(scenario, problems, author="advperc_ros shift_traffic", affiliation="advperc_ros",
                                  source=f"{source.name}, traffic {seconds:g} s earlier", file_format=FileFormat.XML)
    with warnings.catch_warnings():  # one per lanelet of a file without lanelet types: the writer's default is right
        warnings.filterwarnings("ignore", message=".*has no lanelet type", category=UserWarning)
        writer.write_to_file(str(target), OverwriteExistingFile.ALWAYS)
    return len(moved)
