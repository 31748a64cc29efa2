"""A team's Autoware log names its objects by UUIDs of its own: random ones (uuid4, as Autoware's trackers
write them) or a counter in the low bytes. import-bag numbers them 1..n (ids every message type holds: a
Marker's id is an int32), the same on every import, keeps each number's UUID in the ground-truth bag, and
an attack on it carries the team's UUIDs in its bag too."""

import json
import uuid

import numpy as np
import pytest
import yaml
from conftest import REPO
from test_import_bag import BUNDLED, OBJECTS, ODOMETRY, drive_of, write_log

from advperc_ros.cli import main
from advperc_ros.core.boxes import BoxSequence
from advperc_ros.params import NODE
from advperc_ros.ros import bag as bags
from advperc_ros.ros import messages as msgs
from advperc_ros.ros.drive_log import import_drive
from advperc_ros.ros.interfaces import autoware

INT32 = 2**31


def _renamed(data: bytes, uuids: dict[int, bytes]) -> bytes:
    """A PredictedObjects message of ours with each object's UUID replaced by the team's (`uuids`: our id -> 16 bytes)."""
    msg = autoware.TYPESTORE.deserialize_cdr(data, autoware.PREDICTED)
    for item in msg.objects:
        ours = autoware.uuid_id(bytes(np.asarray(item.object_id.uuid, dtype=np.uint8)))
        item.object_id.uuid = np.frombuffer(uuids[ours], dtype=np.uint8).copy()
    return bytes(autoware.TYPESTORE.serialize_cdr(msg, autoware.PREDICTED))


def team_log(path, scenario, uuids: dict[int, bytes]):
    stamps = [int(s) for s in scenario.stamps_ns]
    objects = [(t, _renamed(autoware.encode_predicted(scenario.agents.frame(k), t), uuids)) for k, t in enumerate(stamps)]
    odometry = [(stamps[k], msgs.ego_to_cdr(ego, stamps[k])) for k, ego in enumerate(drive_of(scenario))]
    return write_log(path, {OBJECTS: (autoware.PREDICTED, objects), ODOMETRY: ("nav_msgs/msg/Odometry", odometry)})


@pytest.fixture(scope="module")
def bundled():
    return bags.read_scenario(BUNDLED)


def _layouts(scenario) -> dict[str, dict[int, bytes]]:
    ids = sorted(set(scenario.agents.ids[scenario.agents.valid].tolist()))
    rng = np.random.default_rng(7)
    return {
        "uuid4": {i: uuid.UUID(bytes=rng.bytes(16), version=4).bytes for i in ids},
        "counter in the low bytes": {i: bytes(8) + int(n).to_bytes(8, "big") for n, i in enumerate(ids)},
    }


@pytest.mark.parametrize("layout", ["uuid4", "counter in the low bytes"])
def test_a_log_of_the_team_s_uuids_imports_with_small_ids_and_keeps_its_uuids(tmp_path, bundled, layout):
    uuids = _layouts(bundled)[layout]
    drive = import_drive(team_log(tmp_path / "log", bundled, uuids))
    agents: BoxSequence = drive.scenario.agents
    ids = agents.ids[agents.valid]
    assert ids.min() >= 1 and ids.max() <= len(uuids) < INT32
    # the same objects, renamed: each agent's track is the bundled one's, whose id the UUID was made from
    for new_id, hex_uuid in drive.scenario.object_uuids.items():
        old_id = next(i for i, u in uuids.items() if u.hex() == hex_uuid)
        old = bundled.agents.valid & (bundled.agents.ids == old_id)
        new = agents.valid & (agents.ids == new_id)
        np.testing.assert_allclose(agents.x[new], bundled.agents.x[old], atol=1e-9)
    assert sorted(drive.scenario.object_uuids.values()) == sorted(u.hex() for u in uuids.values())
    again = import_drive(team_log(tmp_path / "log2", bundled, uuids))
    assert np.array_equal(again.scenario.agents.ids, agents.ids)  # a stable numbering


def test_a_uuid_of_our_layout_reads_back_as_itself_and_any_other_in_the_int32_range():
    assert autoware.uuid_id((42).to_bytes(8, "little") + bytes(8)) == 42
    first = autoware.uuid_id(uuid.UUID(int=12345, version=4).bytes)
    assert autoware.HASHED_IDS <= first < INT32 and first == autoware.uuid_id(uuid.UUID(int=12345, version=4).bytes)
    assert autoware.uuid_id(first.to_bytes(8, "little") + bytes(8)) == first  # sent out again, read back the same


def test_import_bag_and_an_attack_carry_the_team_s_uuids_in_their_bags(tmp_path, bundled, capsys):
    uuids = _layouts(bundled)["uuid4"]
    log = team_log(tmp_path / "drive", bundled, uuids)
    assert main(["import-bag", str(log), "--output", str(tmp_path / "bag"), "--params", str(tmp_path / "p.yaml")]) == 0
    imported = bags.read_scenario(tmp_path / "bag")
    assert sorted(imported.object_uuids.values()) == sorted(u.hex() for u in uuids.values())
    params = tmp_path / "p.yaml"  # at the bundled scenario's cruise speed (the recorded drive's is its own, slower)
    document = yaml.safe_load(params.read_text())
    bundled_params = yaml.safe_load((REPO / "config" / "idm_lane_following.yaml").read_text())
    document[NODE]["ros__parameters"]["planner_params"] = bundled_params[NODE]["ros__parameters"]["planner_params"]
    params.write_text(yaml.safe_dump(document))
    assert main(["attack", str(params), "--output", str(tmp_path / "attack"), "--quiet"]) == 0
    metadata = (tmp_path / "attack" / "attack" / "metadata.yaml").read_text()
    assert bags.UUIDS_KEY in metadata
    report = json.loads((tmp_path / "attack" / "report.json").read_text())
    agent = report["collision_agent"]
    assert imported.object_uuids[agent] in metadata  # the agent the attack hid, by the team's own UUID


def test_a_log_recorded_by_ros2_bag_record_imports_with_the_team_s_uuids(tmp_path, bundled, ros_domain):
    """The team's uuid4 log played by `ros2 bag play` and recorded by `ros2 bag record` (rosbag2's own MCAP
    writer, metadata, QoS and receive-time log stamps): it imports as the log written directly does, frame
    for frame, numbered 1..n and with the team's UUIDs kept."""
    import os
    import signal
    import subprocess

    from conftest import need_program

    ros2 = need_program("ros2")
    uuids = _layouts(bundled)["uuid4"]
    played = team_log(tmp_path / "played", bundled, uuids)
    recorded = tmp_path / "recorded"
    logs = (tmp_path / "record.log").open("w")
    record = subprocess.Popen([ros2, "bag", "record", "-s", "mcap", "-o", str(recorded), OBJECTS, ODOMETRY],
                              stdout=logs, stderr=subprocess.STDOUT, start_new_session=True)
    try:  # the recorder subscribes once it sees the player's publishers: the play waits 3 s, then for acknowledgements
        play = subprocess.run([ros2, "bag", "play", str(played), "--rate", "5", "--delay", "3",
                               "--wait-for-all-acked", "5000", "--disable-keyboard-controls"],
                              capture_output=True, text=True, timeout=180)
        assert play.returncode == 0, play.stderr[-2000:]
    finally:
        os.killpg(record.pid, signal.SIGINT)  # rosbag2 closes its bag on SIGINT
        record.wait(timeout=60)
        logs.close()
    assert (recorded / "metadata.yaml").is_file(), (tmp_path / "record.log").read_text()[-2000:]
    direct = import_drive(played).scenario
    drive = import_drive(recorded)
    assert drive.scenario.num_frames == direct.num_frames, (tmp_path / "record.log").read_text()[-2000:]
    for field in ("ids", "valid", "x", "y", "yaw", "vx", "vy", "length", "width"):
        np.testing.assert_array_equal(getattr(drive.scenario.agents, field), getattr(direct.agents, field), err_msg=field)
    assert drive.scenario.object_uuids == direct.object_uuids
    assert sorted(drive.scenario.object_uuids.values()) == sorted(u.hex() for u in uuids.values())
