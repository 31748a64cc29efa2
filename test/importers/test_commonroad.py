"""CommonRoad recordings: import, feasibility, attack or a clear rejection, for every sample.

The samples live in ../shared/data/commonroad/ (input data, never committed); these tests skip
with a reason when that folder or commonroad-io is absent.
"""

import json

import numpy as np
import pytest
import yaml

from conftest import REPO

from advperc_ros.backends.embedded import Stack
from advperc_ros.cli import main
from advperc_ros.configs import core_configs
from advperc_ros.core.perception_errors import PerceptionErrors
from advperc_ros.core.feasibility import unavoidable_collision
from advperc_ros.core.scenario_spec import build_scenario
from advperc_ros.params import load_params
from advperc_ros.ros.bag import read_scenario

DATA = REPO.parent / "shared" / "data" / "commonroad"
# sample -> (recorded vehicles, frames, outcome of an attack with the IDM planner)
SAMPLES = {
    "USA_US101-1_1_T-1": (2, 61, "no influential agent"),
    "USA_US101-10_1_T-1": (44, 81, "rear-ended with perfect perception"),
    "USA_Lanker-2_1_T-1": (43, 91, "no influential agent"),
    "USA_Peach-2_1_T-1": (16, 106, "no influential agent"),
}

needs_data = pytest.mark.skipif(not DATA.is_dir(), reason=f"CommonRoad samples not found at {DATA}")


@pytest.fixture(scope="module")
def commonroad():
    return pytest.importorskip("commonroad", reason="commonroad-io is not installed (pip install '.[commonroad]')")


@needs_data
@pytest.mark.parametrize("name", SAMPLES)
def test_sample_imports_and_attacks_or_is_refused_with_a_reason(name, tmp_path, capsys, commonroad):
    from commonroad.common.file_reader import CommonRoadFileReader

    vehicles, frames, outcome = SAMPLES[name]
    bag, params = tmp_path / "bag", tmp_path / "params.yaml"
    assert main(["import-commonroad", str(DATA / f"{name}.xml"), "--output", str(bag), "--params", str(params)]) == 0
    scenario = read_scenario(bag)
    assert scenario.agents.shape == (frames, vehicles)

    # every recorded state arrives in the bag at its time step
    recorded, problems = CommonRoadFileReader(str(DATA / f"{name}.xml")).open()
    slots = {int(i): j for j, i in enumerate(scenario.agents.ids.max(axis=0))}
    for obstacle in recorded.dynamic_obstacles[:5]:
        j = slots[obstacle.obstacle_id]
        for state in [obstacle.initial_state, *obstacle.prediction.trajectory.state_list]:
            k = state.time_step
            assert scenario.agents.valid[k, j]
            np.testing.assert_allclose([scenario.agents.x[k, j], scenario.agents.y[k, j]], state.position, atol=1e-9)
        assert scenario.agents.valid[:, j].sum() == 1 + len(obstacle.prediction.trajectory.state_list)
    start = list(problems.planning_problem_dict.values())[0].initial_state
    assert np.hypot(scenario.ego_start.x - start.position[0], scenario.ego_start.y - start.position[1]) < 2.0

    document = yaml.safe_load(params.read_text())
    document["orchestrator"]["ros__parameters"]["search"] = {"random": {"steps": 4, "proposals": 20}}
    params.write_text(yaml.safe_dump(document))
    capsys.readouterr()
    code = main(["attack", str(params), "--output", str(tmp_path / "out"), "--quiet"])
    capsys.readouterr()
    if outcome == "rear-ended with perfect perception":
        # not the ego's fault, so the attack goes on: no drop makes it the ego's, not even all at once, so
        # the approach phase runs (cars near the ego shown wrongly) ...
        assert code == 0
        report = json.loads((tmp_path / "out" / "report.json").read_text())
        assert report["joint_agents"] == [] and report["approach"]["rollouts"] >= report["params"]["search.approach.patience"]
        # ... but counting every collision, the recording is refused as the ego collides unattacked
        document["orchestrator"]["ros__parameters"]["rule"]["name"] = "collision"
        params.write_text(yaml.safe_dump(document))
        code = main(["attack", str(params), "--output", str(tmp_path / "every"), "--quiet"])
        assert code == 1 and "perfect perception" in capsys.readouterr().err
        assert not (tmp_path / "every").exists()
    else:
        assert code == 0
        report = json.loads((tmp_path / "out" / "report.json").read_text())
        assert report["collision"] is False and "no agent" in report["message"]
        # ground truth, each agent dropped once, then all at once (the joint drops' blind rollout, clear),
        # then the approach phase's steps (nearby cars shown displaced), none colliding
        steps, patience = report["params"]["search.approach.steps"], report["params"]["search.approach.patience"]
        approached = report["approach"]["rollouts"]
        assert report["rollouts"] == 1 + vehicles + 1 + approached and report["joint_agents"] == []
        assert patience <= approached <= steps and report["approach"]["closest_margin"] > 0.0


@needs_data
def test_urban_turn_imports_for_both_planners_and_obp_drives_it(tmp_path, commonroad):
    """Lankershim, a left turn at an intersection: an IDM and an ObP params file, both counting only
    at-fault collisions (recorded traffic does not react to the ego); ObP's ground-truth rollout
    runs every frame and takes the turn."""
    bag, params = tmp_path / "bag", tmp_path / "lanker.yaml"
    assert main(["import-commonroad", str(DATA / "USA_Lanker-2_3_T-1.xml"), "--output", str(bag),
                 "--params", str(params)]) == 0
    idm, obp = load_params(params), load_params(tmp_path / "lanker.obp.yaml")
    reactive = load_params(tmp_path / "lanker.reactive.yaml")  # loads without the plug-in: it is built at attack
    fiss = load_params(tmp_path / "lanker.fiss.yaml")
    assert (idm.planner, obp.planner, reactive.planner, fiss.planner) == (
        "idm", "obp", "advperc_ros.contrib.reactive:ReactivePlanner", "advperc_ros.contrib.fiss:FissPlanner")
    assert idm.planner_params == obp.planner_params == reactive.planner_params == fiss.planner_params
    assert obp.planner_params["target_speed"] > 1.0
    assert idm.rule.name == obp.rule.name == reactive.rule.name == "at_fault_collision"
    assert idm.bag == obp.bag == reactive.bag == str(bag.resolve())

    scenario = read_scenario(bag)
    result = Stack(scenario, core_configs(obp)).rollout(PerceptionErrors.none(*scenario.agents.shape))
    assert result.inconclusive is None and result.num_frames == scenario.num_frames
    heading = np.unwrap(result.ego[:, 2])
    assert heading.max() - heading.min() > 1.0  # the ego turned (about 1.5 rad)


@needs_data
def test_a_junction_tighter_than_a_car_turns_is_rounded_and_obp_drives_it(tmp_path, capsys, commonroad):
    """Peachtree, a right turn whose lanelets turn at a 2.7 m radius: the route is rounded to 5 m (said
    on import) and stays within a metre of the map's centre lines, and ObP's ground truth takes the
    turn without one failed solve (before, 25 of its 51 solves failed and, with every
    car hidden, all 51: that ego never left the junction); blind, it pulls out into a car."""
    from advperc_ros.core.geometry import sharpest_turn
    from advperc_ros.importers.commonroad import ROUTE_MIN_RADIUS

    bag = tmp_path / "bag"
    capsys.readouterr()
    assert main(["import-commonroad", str(DATA / "USA_Peach-3_2_T-1.xml"), "--output", str(bag)]) == 0
    assert "its corners rounded to a 5 m radius" in capsys.readouterr().out
    scenario = read_scenario(bag)
    assert sharpest_turn(scenario.route) <= 1.0 / ROUTE_MIN_RADIUS + 1e-9
    # every point of the route within a metre of the map's centre lines (sampled every 25 cm)
    centres = np.concatenate([lane.centerline.position(np.arange(0.0, lane.centerline.length, 0.25))
                              for lane in scenario.lanes])
    gaps = np.linalg.norm(scenario.route.points[:, None, :] - centres[None, :, :], axis=2).min(axis=1)
    assert gaps.max() < 1.0
    obp = load_params(tmp_path / "bag.obp.yaml")
    stack = Stack(scenario, core_configs(obp))
    result = stack.rollout(PerceptionErrors.none(*scenario.agents.shape))
    assert result.inconclusive is None and result.planner_failures == 0 and not result.collided
    heading = np.unwrap(result.ego[:, 2])
    assert heading.max() - heading.min() > 1.0  # the ego turned
    blind = PerceptionErrors.none(*scenario.agents.shape)
    blind.fn[:] = True  # every car hidden: the ego now pulls out, into a car's side, at its fault
    hidden = stack.rollout(blind)
    assert hidden.planner_failures == 0 and hidden.collided and hidden.counted.min() < 0.0


@needs_data
def test_unavoidable_recording_is_rejected_and_nothing_written(tmp_path, capsys, commonroad):
    """A recorded car parked on the ego's start: no ego motion escapes it."""
    from commonroad.common.file_reader import CommonRoadFileReader
    from commonroad.common.file_writer import CommonRoadFileWriter, OverwriteExistingFile
    from commonroad.common.util import FileFormat
    from commonroad.geometry.obstacle_shapes.rect_obstacle_shape import RectObstacleShape
    from commonroad.prediction.prediction import TrajectoryPrediction
    from commonroad.scenario.obstacle import DynamicObstacle, ObstacleType
    from commonroad.scenario.state import CustomState, InitialState
    from commonroad.scenario.trajectory import Trajectory

    scenario, problems = CommonRoadFileReader(str(DATA / "USA_US101-1_1_T-1.xml")).open()
    start = list(problems.planning_problem_dict.values())[0].initial_state
    shape = RectObstacleShape(width=1.8, length=4.5)
    states = [CustomState(time_step=k, position=np.array(start.position), orientation=start.orientation, velocity=0.0)
              for k in range(1, 60)]
    blocker = DynamicObstacle(
        scenario.generate_object_id(), ObstacleType.CAR, shape,
        InitialState(time_step=0, position=np.array(start.position), orientation=start.orientation, velocity=0.0,
                     acceleration=0.0, yaw_rate=0.0, slip_angle=0.0),
        TrajectoryPrediction(Trajectory(1, states), shape),
    )
    scenario.add_objects(blocker)
    path = tmp_path / "blocked.xml"
    CommonRoadFileWriter(scenario, problems, author="test", affiliation="test", source="test",
                         file_format=FileFormat.XML).write_to_file(str(path), OverwriteExistingFile.ALWAYS)
    capsys.readouterr()
    code = main(["import-commonroad", str(path), "--output", str(tmp_path / "bag"), "--params", str(tmp_path / "p.yaml")])
    err = capsys.readouterr().err.strip()
    assert code == 3
    assert "blocked.xml" in err and "rejected" in err and len(err.splitlines()) == 1
    assert not any(tmp_path / name for name in ("bag", "p.yaml", "p.obp.yaml", "p.reactive.yaml", "p.fiss.yaml") if (tmp_path / name).exists())


def test_feasibility_tells_unavoidable_from_avoidable():
    spec = {
        "name": "rear_end", "dt": 0.1, "duration": 6.0,
        "lanes": [{"id": "east", "centerline": [[-300.0, 0.0], [500.0, 0.0]], "width": 3.5},
                  {"id": "east2", "centerline": [[-300.0, 3.5], [500.0, 3.5]], "width": 3.5}],
        "ego": {"route": ["east"], "start_s": 300.0, "speed": 10.0},
        "agents": [{"id": 1, "lane": "east", "start_s": 280.0, "speed": 35.0}],
    }
    assert "whatever it does" in unavoidable_collision(build_scenario(spec), 4.6, 1.9)
    spec["agents"][0]["lane"] = "east2"  # the fast car passes in the next lane
    assert unavoidable_collision(build_scenario(spec), 4.6, 1.9) is None
    spec["agents"] = [{"id": 1, "lane": "east", "start_s": 330.0, "speed": 0.0}]  # parked ahead: brake
    assert unavoidable_collision(build_scenario(spec), 4.6, 1.9) is None


def test_missing_commonroad_file_is_bad_input(tmp_path, capsys, commonroad):
    code = main(["import-commonroad", str(tmp_path / "nope.xml")])
    err = capsys.readouterr().err
    assert code == 2 and "nope.xml" in err
