"""`advperc import-bag`: a team's own recorded drive (objects in any interface profile's type, the ego's
odometry) becomes a ground-truth bag. A bundled scenario written out as an Autoware log reads back as
the same ground truth and gives the same attack; a log without a map gets a corridor around the
driven path; bad logs are refused in one line before anything is written."""

import json
from pathlib import Path

import numpy as np
import pytest
import yaml
from rosbags.rosbag2 import StoragePlugin, Writer

from conftest import REPO
from test_cli import SMALL_SEARCH

from advperc_ros.backends.embedded import Stack
from advperc_ros.cli import main
from advperc_ros.configs import core_configs
from advperc_ros.core.perception_errors import PerceptionErrors
from advperc_ros.core.scenario import EgoState
from advperc_ros.params import AttackParams
from advperc_ros.ros import cdr
from advperc_ros.ros import messages as msgs
from advperc_ros.ros.bag import read_scenario, read_topics
from advperc_ros.ros.drive_log import import_drive
from advperc_ros.ros.interfaces import autoware, vision
from advperc_ros.ros.topics import LANES, ROUTE

BUNDLED = REPO / "bags" / "idm_lane_following"
ODOMETRY = "/localization/kinematic_state"
OBJECTS = "/perception/object_recognition/objects"


def write_log(path: Path, topics: dict[str, tuple[str, list[tuple[int, bytes]]]],
              storage: StoragePlugin = StoragePlugin.MCAP) -> Path:
    """A rosbag2 log as a team records one: topic -> (type, [(log time, CDR payload)])."""
    writer = Writer(path, version=9, storage_plugin=storage)
    writer.open()
    try:
        for topic, (msgtype, messages) in topics.items():
            connection = writer.add_connection(topic, msgtype, typestore=cdr.TYPESTORE)
            for log_time, data in messages:
                writer.write(connection, log_time, data)
    finally:
        writer.close()
    return path


def drive_of(scenario):
    """The ego's recorded drive: the bundled planner's ground-truth rollout (what a log of that drive holds)."""
    params = AttackParams(bag=str(BUNDLED))
    rollout = Stack(scenario, core_configs(params)).rollout(PerceptionErrors.none(*scenario.agents.shape))
    return [EgoState(*row) for row in rollout.ego]


def autoware_log(path: Path, scenario, with_map: bool, every: int = 1, offset_ns: int = 0) -> Path:
    stamps = [int(s) + offset_ns for s in scenario.stamps_ns]
    drive = drive_of(scenario)
    objects = [(t, autoware.encode_predicted(scenario.agents.frame(k), t)) for k, t in enumerate(stamps) if k % every == 0]
    odometry = [(stamps[k], msgs.ego_to_cdr(ego, stamps[k])) for k, ego in enumerate(drive)]
    topics = {OBJECTS: (autoware.PREDICTED, objects), ODOMETRY: ("nav_msgs/msg/Odometry", odometry)}
    if with_map:
        bundled, _ = read_topics(BUNDLED, [LANES, ROUTE], raw=True)
        topics[LANES] = ("visualization_msgs/msg/MarkerArray", bundled[LANES])
        topics[ROUTE] = ("nav_msgs/msg/Path", bundled[ROUTE])
    return write_log(path, topics)


@pytest.fixture(scope="module")
def bundled():
    return read_scenario(BUNDLED)


def test_an_autoware_log_of_a_bundled_scenario_reads_back_as_its_ground_truth(tmp_path, bundled):
    drive = import_drive(autoware_log(tmp_path / "log", bundled, with_map=True))
    got = drive.scenario
    assert (drive.objects_topic, drive.odometry_topic) == (OBJECTS, ODOMETRY)
    assert np.array_equal(got.stamps_ns, bundled.stamps_ns)
    assert np.array_equal(got.agents.valid, bundled.agents.valid)
    assert np.array_equal(got.agents.ids[got.agents.valid], bundled.agents.ids[bundled.agents.valid])
    for field in ("x", "y", "yaw", "vx", "vy", "length", "width", "height"):
        np.testing.assert_allclose(getattr(got.agents, field)[got.agents.valid],
                                   getattr(bundled.agents, field)[bundled.agents.valid], rtol=0, atol=1e-9, err_msg=field)
    assert got.ego_start == bundled.ego_start
    assert np.array_equal(got.route.points, bundled.route.points)
    assert [(lane.id, lane.width) for lane in got.lanes] == [(lane.id, lane.width) for lane in bundled.lanes]


def test_the_imported_log_gives_the_bundled_bag_s_attack(tmp_path, bundled):
    """`advperc import-bag` of the log (named as the scenario), then the bundled params file's attack on the
    imported bag: the attack of the bundled bag."""
    log = autoware_log(tmp_path / "idm_lane_following", bundled, with_map=True)
    assert main(["import-bag", str(log), "--output", str(tmp_path / "bag")]) == 0
    assert (tmp_path / "bag.yaml").is_file() and (tmp_path / "bag.obp.yaml").is_file()
    reports = {}
    for name, bag in (("imported", tmp_path / "bag"), ("bundled", BUNDLED)):
        document = yaml.safe_load((BUNDLED.parent.parent / "config" / "idm_lane_following.yaml").read_text())
        params = document["orchestrator"]["ros__parameters"]
        params["bag"] = str(bag)
        params["search"]["random"].update(SMALL_SEARCH)
        path = tmp_path / f"{name}.yaml"
        path.write_text(yaml.safe_dump(document))
        assert main(["attack", str(path), "--output", str(tmp_path / name), "--quiet"]) == 0
        reports[name] = json.loads((tmp_path / name / "report.json").read_text())
    for report in reports.values():
        for key in ("bag", "bag_sha256", "wall_time_s", "config_hash"):
            report.pop(key)
    for report in reports.values():
        report["params"].pop("bag")
    assert reports["imported"] == reports["bundled"]
    assert reports["bundled"]["collision"] is True
    errors = [np.load(tmp_path / name / "attack_errors.npz") for name in ("imported", "bundled")]
    for key in errors[1].files:
        np.testing.assert_allclose(errors[0][key], errors[1][key], rtol=0, atol=1e-9, err_msg=key)


def test_a_log_without_a_map_gets_a_corridor_round_the_driven_path_and_is_resampled(tmp_path, bundled):
    """Objects at 5 Hz, 0.05 s after the frames, read at 10 Hz: frames between two messages are
    interpolated, frames on one are that message exactly; the route is the driven path, extended ahead."""
    log = autoware_log(tmp_path / "log", bundled, with_map=False, every=2)
    drive = import_drive(log)
    got = drive.scenario
    assert drive.road == "a corridor around the recorded ego path"
    assert [lane.id for lane in got.lanes] == ["route", "left1", "right1"]
    assert got.route.length > 300.0 and got.route.points[0, 1] == pytest.approx(bundled.ego_start.y)
    offsets = [np.min(np.abs(lane.centerline.points[:, 1] - got.route.points[:, 1])) for lane in got.lanes[1:]]
    assert offsets == pytest.approx([3.5, 3.5])
    # frame 2 (a message) exactly; frame 1 (between messages 0 and 2) halfway for a car moving straight
    for k in (1, 2):
        valid = got.agents.valid[k] & bundled.agents.valid[k] & bundled.agents.valid[k - 1]
        np.testing.assert_allclose(got.agents.x[k, valid], bundled.agents.x[k, valid], rtol=0, atol=1e-6)


@pytest.mark.parametrize("topics, says", [
    ({OBJECTS: (autoware.PREDICTED, [(0, autoware.encode_predicted({"ids": np.zeros(0, np.int64), **{
        f: np.zeros(0) for f in ("x", "y", "yaw", "vx", "vy", "length", "width", "height", "score")}}, 0))])},
     "no odometry topic (a topic of type nav_msgs/msg/Odometry)"),
    ({OBJECTS: (autoware.PREDICTED, []), ODOMETRY: ("nav_msgs/msg/Odometry", [(0, msgs.ego_to_cdr(EgoState(0, 0, 0, 1), 0))])},
     f"topic '{OBJECTS}' holds no messages"),
    ({ODOMETRY: ("nav_msgs/msg/Odometry", [(0, msgs.ego_to_cdr(EgoState(0, 0, 0, 1), 0))])}, "no objects topic"),
])
def test_a_log_missing_a_topic_is_one_line_and_nothing_written(tmp_path, capsys, topics, says):
    log = write_log(tmp_path / "log", topics)
    assert main(["import-bag", str(log), "--output", str(tmp_path / "bag")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and says in err and str(log) in err, err
    assert not (tmp_path / "bag").exists() and not (tmp_path / "bag.yaml").exists()


def test_an_objects_topic_of_another_type_is_refused_naming_it(tmp_path, capsys, bundled):
    log = autoware_log(tmp_path / "log", bundled, with_map=False)
    assert main(["import-bag", str(log), "--objects", ODOMETRY, "--output", str(tmp_path / "bag")]) == 2
    err = capsys.readouterr().err.strip()
    assert f"topic '{ODOMETRY}' has type 'nav_msgs/msg/Odometry', not one of" in err and len(err.splitlines()) == 1


def test_vision_msgs_detections_in_a_sqlite3_log_import_too(tmp_path, bundled):
    stamps = [int(s) for s in bundled.stamps_ns[:20]]
    detections = [(t, vision.encode_detections(bundled.agents.frame(k), t)) for k, t in enumerate(stamps)]
    odometry = [(t, msgs.ego_to_cdr(ego, t)) for t, ego in zip(stamps, drive_of(bundled))]
    log = write_log(tmp_path / "log", {"/detections": (vision.DETECTIONS, detections),
                                       ODOMETRY: ("nav_msgs/msg/Odometry", odometry)}, StoragePlugin.SQLITE3)
    got = import_drive(log).scenario
    assert got.num_frames == 20
    np.testing.assert_allclose(got.agents.x[got.agents.valid], bundled.agents.x[:20][bundled.agents.valid[:20]])
