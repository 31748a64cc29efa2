"""The ground-truth bag contract and `advperc check-bag`: a bundled bag passes with a summary;
each kind of broken bag fails with one line naming the bag and the topic or field (exit code 2),
and read_scenario refuses it with the first of those lines.

The contract's two rules that used to be silent: two objects with one id in a frame are an error
(one of them was dropped), and so are frames whose header stamps do not strictly increase in the
bag's order (they were re-sorted)."""

from pathlib import Path

import numpy as np
import pytest
from rosbags.rosbag2 import StoragePlugin, Writer

from advperc_ros.cli import main
from advperc_ros.ros import topics
from advperc_ros.ros import cdr
from advperc_ros.ros import messages as msgs
from advperc_ros.ros.bag import check_ground_truth, read_objects, read_scenario
from advperc_ros.exceptions import BagError

DT = 100_000_000
SIZE_FIELDS = ("length", "width", "height")
LANE = ([(0.0, -1.75), (100.0, -1.75)], 3.5)


def boxes(ids: list[int], **values: float) -> dict[str, np.ndarray]:
    """A frame of objects with ids `ids`: each at x = 10 * id, 4.5 x 1.8 x 1.5 m, moving at 5 m/s,
    unless `values` says otherwise (one value for all)."""
    ids = np.array(ids, dtype=np.int64)
    out = {"ids": ids, "x": 10.0 * ids, "y": np.full(len(ids), -1.75), "yaw": np.zeros(len(ids)),
           "vx": np.full(len(ids), 5.0), "vy": np.zeros(len(ids)), "length": np.full(len(ids), 4.5),
           "width": np.full(len(ids), 1.8), "height": np.full(len(ids), 1.5), "score": np.full(len(ids), np.nan)}
    out.update({name: np.full(len(ids), value, dtype=float) for name, value in values.items()})
    return out


def marker_lanes(lanes: list[tuple[list[tuple[float, float]], float]]) -> object:
    """Lanes as /map/lanes markers, points and widths as given (no Polyline: it refuses some)."""
    Marker = msgs.T["visualization_msgs/msg/Marker"]
    markers = [msgs._marker(0, msgs.LANES_NS, i, Marker.LINE_STRIP, Marker.ADD, msgs.pose(0, 0, 0), (width, 0, 0),
                            msgs._color("lanes"), [msgs._point(x, y) for x, y in points], f"lane{i}")
               for i, (points, width) in enumerate(lanes)]
    return msgs.T["visualization_msgs/msg/MarkerArray"](markers=markers)


def write_bag(path: Path, frames: list[dict] | None = None, stamps: list[int] | None = None,
              odometry: tuple | list[tuple] | None = (5.0, -1.75, 0.0, 8.0), route: list | None = ((0.0, -1.75), (100.0, -1.75)),
              lanes: list | None = (LANE,), wrong_type: str | None = None, clock: bool = False) -> Path:
    """A ground-truth bag as a team might record it: frames of objects at `stamps` (default every
    0.1 s), the ego's start, route and lanes (None leaves a topic out), /clock with `clock`; `wrong_type`
    records that topic as a std_msgs/String instead; a list of `odometry` tuples, one message each. Written with rosbags directly, so anything can go in."""
    frames = [boxes([1, 2]) for _ in range(4)] if frames is None else frames
    stamps = [k * DT for k in range(len(frames))] if stamps is None else stamps
    messages = []
    if lanes is not None:
        messages.append((topics.LANES, 0, cdr.payload(marker_lanes(list(lanes)), topics.TOPIC_TYPES[topics.LANES])))
    if route is not None:
        points = np.array(route, dtype=float).reshape(-1, 2)
        messages.append((topics.ROUTE, 0, cdr.encode_path(points[:, 0], points[:, 1], np.zeros(len(points)), [0] * len(points), 0)))
    if odometry is not None:
        messages += [(topics.ODOMETRY, k * DT, cdr.encode_odometry(*ego, k * DT))
                     for k, ego in enumerate(odometry if isinstance(odometry, list) else [odometry])]
    messages += [(topics.GROUND_TRUTH, k, cdr.encode_objects(frame, stamp, "ground_truth"))
                 for k, (frame, stamp) in enumerate(zip(frames, stamps))]
    if clock:  # /clock at every frame, as a recording of a sim-time stack has it
        messages += [(topics.CLOCK, k, cdr.encode_clock(stamp)) for k, stamp in enumerate(stamps)]
    writer = Writer(path, version=9, storage_plugin=StoragePlugin.MCAP)
    writer.open()
    connections = {}
    for topic, log_time, data in messages:
        msgtype = topics.TOPIC_TYPES[topic]
        if topic == wrong_type:
            msgtype, data = "std_msgs/msg/String", cdr.payload(msgs.string("not this"), "std_msgs/msg/String")
        if topic not in connections:
            connections[topic] = writer.add_connection(topic, msgtype, typestore=msgs.TYPESTORE)
        writer.write(connections[topic], log_time, data)
    writer.close()
    return path


def check_bag(path: Path, capsys) -> tuple[int, str, list[str]]:
    """(exit code, stdout, stderr lines) of `advperc check-bag path`; the bag is left as it was."""
    before = sorted((p.name, p.stat().st_mtime_ns) for p in path.iterdir()) if path.is_dir() else None
    capsys.readouterr()
    code = main(["check-bag", str(path)])
    out, err = capsys.readouterr()
    assert (sorted((p.name, p.stat().st_mtime_ns) for p in path.iterdir()) if path.is_dir() else None) == before
    return code, out, err.splitlines()


def test_bundled_bag_passes_with_a_summary(repo, capsys):
    code, out, err = check_bag(repo / "bags" / "idm_lane_following", capsys)
    assert (code, err) == (0, [])
    assert "ok" in out and "251 frames" in out and "5 agents" in out and "25.000 s" in out and "3 lanes" in out
    for topic in (topics.GROUND_TRUTH, topics.ODOMETRY, topics.ROUTE, topics.LANES, topics.CLOCK):
        assert topic in out


def test_a_bag_written_here_passes_and_reads_back(tmp_path, capsys):
    path = write_bag(tmp_path / "fine", frames=[boxes([1, 2]), boxes([]), boxes([2]), boxes([1, 2, 3])])
    code, out, _ = check_bag(path, capsys)
    assert code == 0 and "4 frames" in out and "3 agents" in out
    scenario = read_scenario(path)
    assert scenario.agents.valid.tolist() == [[True, True, False], [False, False, False], [False, True, False],
                                              [True, True, True]]


# (what is written, words the one line must hold besides the bag's path)
BROKEN = {
    "duplicate id": (dict(frames=[boxes([1, 2]), boxes([1, 2]), boxes([2, 2]), boxes([1, 2])]),
                     [topics.GROUND_TRUTH, "frame 2", "'id'", "object 2", "twice"]),
    "stamps out of order": (dict(stamps=[0, 2 * DT, DT, 3 * DT]), [topics.GROUND_TRUTH, "frame 2", "'header.stamp'", "order"]),
    "repeated stamp": (dict(stamps=[0, DT, DT, 2 * DT]), [topics.GROUND_TRUTH, "frame 2", "'header.stamp'"]),
    "irregular stamps": (dict(stamps=[0, DT, 3 * DT, 4 * DT]), ["'header.stamp'", "constant period"]),
    "frames 1 ns apart (caught only after a rollout of it)": (dict(stamps=[0, 1, 2, 3]),
                                                             ["'header.stamp'", "steps by 1 ns", "between 0.001 and 60 s"]),
    "frames 1e6 s apart": (dict(stamps=[0, 10**15, 2 * 10**15, 3 * 10**15]), ["'header.stamp'", "between 0.001 and 60 s"]),
    "one frame": (dict(frames=[boxes([1])]), ["'frames'", "two frames"]),
    "no ground truth": (dict(frames=[]), [topics.GROUND_TRUTH, "missing"]),
    "nan position": (dict(frames=[boxes([1]), boxes([1], x=np.nan)]), ["'x'", "agent 1", "frame 1"]),
    "infinite velocity": (dict(frames=[boxes([1]), boxes([1], vx=np.inf)]), ["'vx'", "agent 1", "frame 1"]),
    "zero size": (dict(frames=[boxes([1]), boxes([1], width=0.0)]), ["'width'", "agent 1", "frame 1"]),
    "no odometry": (dict(odometry=None), [topics.ODOMETRY, "missing"]),
    "nan odometry": (dict(odometry=(np.nan, 0.0, 0.0, 8.0)), ["'ego.start'", "finite"]),
    "two odometry messages": (dict(odometry=[(5.0, -1.75, 0.0, 8.0), (5.8, -1.75, 0.0, 8.0)]),
                              [topics.ODOMETRY, "2 messages", "the ego's start only"]),
    "no route": (dict(route=None), [topics.ROUTE, "missing"]),
    "route of one point": (dict(route=[(0.0, 0.0), (0.0, 0.0)]), [topics.ROUTE, "'poses'", "two distinct points"]),
    "nan route": (dict(route=[(0.0, 0.0), (np.nan, 1.0)]), [topics.ROUTE, "'poses'", "finite"]),
    "lane at 1e300 (its length overflowed, with a warning before the line)": (
        dict(lanes=[([(0.0, 0.0), (1e300, 0.0)], 3.5)]), [topics.LANES, "lane0", "beyond"]),
    "route at 1e300": (dict(route=[(0.0, 0.0), (1e300, 1.0)]), [topics.ROUTE, "'poses'", "beyond"]),
    "lane of one point": (dict(lanes=[([(1.0, 1.0)], 3.5)]), [topics.LANES, "lane0", "two distinct points"]),
    "negative lane width": (dict(lanes=[([(0.0, 0.0), (9.0, 0.0)], -3.5)]), ["'width'", "lane0", "positive"]),
    "ground truth of another type": (dict(wrong_type=topics.GROUND_TRUTH), [topics.GROUND_TRUTH, "std_msgs/msg/String"]),
    "route of another type": (dict(wrong_type=topics.ROUTE), [topics.ROUTE, "std_msgs/msg/String"]),
}


@pytest.mark.parametrize("kind", BROKEN)
def test_each_kind_of_broken_bag_fails_with_its_line(kind, tmp_path, capsys):
    written, words = BROKEN[kind]
    path = write_bag(tmp_path / "broken", **written)
    code, out, err = check_bag(path, capsys)
    assert (code, out, len(err)) == (2, "", 1), err
    assert err[0].startswith(f"advperc: error: {path}")
    for word in words:
        assert word in err[0], (word, err[0])
    with pytest.raises(BagError) as caught:
        read_scenario(path)
    assert f"advperc: error: {caught.value}" == err[0]


def test_every_problem_gets_its_own_line(tmp_path, capsys):
    path = write_bag(tmp_path / "broken", frames=[boxes([1, 1]), boxes([1])], odometry=None, wrong_type=topics.ROUTE)
    code, _, err = check_bag(path, capsys)
    assert code == 2 and len(err) == 3
    assert [topic for line in err for topic in (topics.GROUND_TRUTH, topics.ODOMETRY, topics.ROUTE) if topic in line] == [
        topics.GROUND_TRUTH, topics.ODOMETRY, topics.ROUTE]


def test_unreadable_and_missing_bags_fail_with_one_line(tmp_path, capsys):
    broken = tmp_path / "garbage"
    broken.mkdir()
    (broken / "metadata.yaml").write_text("rosbag2_bagfile_information:\n  version: [9\n")
    (broken / "garbage.mcap").write_bytes(b"not an mcap file")
    for path in (broken, tmp_path / "absent"):
        code, out, err = check_bag(path, capsys)
        assert (code, out, len(err)) == (2, "", 1) and str(path) in err[0]


def test_the_contract_holds_for_every_object_topic(tmp_path):
    """read_objects (advperc score, pem fit) reads detections under the same two rules."""
    path = write_bag(tmp_path / "dup", frames=[boxes([1]), boxes([3, 3])])
    with pytest.raises(BagError, match=r"topic '/ground_truth/objects', frame 1: field 'id'"):
        read_objects(path, topics.GROUND_TRUTH)
    path = write_bag(tmp_path / "back", stamps=[0, DT, 3 * DT, 2 * DT])
    with pytest.raises(BagError, match=r"frame 3: field 'header.stamp' \(200000000 ns\) is not after frame 2's"):
        read_objects(path, topics.GROUND_TRUTH)
    assert check_ground_truth(path).scenario is None
