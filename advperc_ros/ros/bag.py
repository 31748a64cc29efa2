"""rosbag2 MCAP bags of the topic contract: ground-truth bags in, attack bags out.

Bags are written with rosbags (storage MCAP, metadata version 9, CDR, ros2msg schemas), so `ros2
bag info`, Foxglove and the mcap-ros2-support decoder read them. A bag is written into a hidden
sibling directory and renamed into place once complete: a killed run leaves no bag that looks whole.
"""

import hashlib
import json
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import yaml
from rosbags.interfaces import Connection
from rosbags.rosbag2 import Reader, StoragePlugin, Writer
from rosbags.rosbag2.metadata import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime

from advperc_ros.core.boxes import MAGNITUDE_BOUND, BoxSequence
from advperc_ros.core.geometry import Polyline
from advperc_ros.core.scenario import EgoState, Lane, Scenario
from advperc_ros.core.staging import staged_folder
from advperc_ros.exceptions import BagError, MessageError
from advperc_ros.ros import cdr
from advperc_ros.ros import messages as msgs
from advperc_ros.ros.topics import CLOCK, GROUND_TRUTH, LANES, LATCHED, ODOMETRY, ROUTE, TOPIC_TYPES, depth

SCENARIO_KEY = "advperc.scenario"
UUIDS_KEY = "advperc.object_uuids"  # custom data: {agent id: the UUID its stack named it by}, for imported drives
ROS_DISTRO = "jazzy"  # the message definitions come from rosbags' Jazzy typestore


def _qos(latched: bool) -> Qos:
    infinite = QosTime(sec=0x7FFFFFFF, nsec=0xFFFFFFFF)
    return Qos(
        history=QosHistory.KEEP_LAST,
        depth=depth(latched),
        reliability=QosReliability.RELIABLE,
        durability=QosDurability.TRANSIENT_LOCAL if latched else QosDurability.VOLATILE,
        deadline=infinite,
        lifespan=infinite,
        liveliness=QosLiveliness.AUTOMATIC,
        liveliness_lease_duration=infinite,
        avoid_ros_namespace_conventions=False,
    )


class BagWriter:
    """Writes contract topics by name; connections are created on first use."""

    def __init__(self, writer: Writer) -> None:
        self._writer = writer
        self._connections: dict[str, Connection] = {}

    def write(self, topic: str, ns_time: int, message, msgtype: str | None = None) -> None:
        """Write a rosbags message, or its CDR payload (bytes, as `cdr` encodes it); `msgtype` for a
        topic outside the contract (an interface profile's)."""
        msgtype = msgtype or TOPIC_TYPES[topic]
        if topic not in self._connections:
            self._connections[topic] = self._writer.add_connection(
                topic, msgtype, typestore=msgs.TYPESTORE, offered_qos_profiles=[_qos(topic in LATCHED)]
            )
        self._writer.write(self._connections[topic], int(ns_time), cdr.payload(message, msgtype))

    def set_custom_data(self, key: str, value: str) -> None:
        self._writer.set_custom_data(key, value)


@contextmanager
def open_bag_for_writing(path: Path) -> Iterator[BagWriter]:
    """A bag directory at `path` (its file is `<name>.mcap` inside), written atomically."""
    path = Path(path)
    if path.exists():
        raise BagError(f"{path}: exists already, not overwriting")
    with staged_folder(path) as staging:
        writer = Writer(staging, version=9, storage_plugin=StoragePlugin.MCAP)
        writer.open()
        try:
            yield BagWriter(writer)
        finally:
            writer.close()
        (staging / f"{staging.name}.mcap").rename(staging / f"{path.name}.mcap")
        _finish_metadata(staging / "metadata.yaml", staging.name, path.name)


def _finish_metadata(metadata: Path, staged: str, final: str) -> None:
    """The metadata rosbags wrote, with the file's final name and the distro the messages are
    from (rosbags writes its own name there; `ros2 bag info` shows it as "ROS Distro")."""
    document = yaml.safe_load(metadata.read_text())
    info = document["rosbag2_bagfile_information"]
    info["relative_file_paths"] = [name.replace(f"{staged}.mcap", f"{final}.mcap") for name in info["relative_file_paths"]]
    for file in info["files"]:
        file["path"] = file["path"].replace(f"{staged}.mcap", f"{final}.mcap")
    info["ros_distro"] = ROS_DISTRO
    metadata.write_text(yaml.safe_dump(document, sort_keys=False))


def digest(path: Path) -> str:
    """sha256 of a bag's messages on the contract's topics (topic, log time, CDR bytes): which data
    was attacked, wherever the bag lies and whatever its file is called."""
    messages, _ = read_topics(path, TOPIC_TYPES, raw=True)
    sha = hashlib.sha256()
    for topic in sorted(messages):
        for log_time, data in messages[topic]:
            sha.update(topic.encode())
            sha.update(log_time.to_bytes(8, "little", signed=True))
            sha.update(data)
    return sha.hexdigest()


def write_scenario_static(bag: BagWriter, scenario: Scenario) -> None:
    """What does not change over a scenario: its name, the lanes and the ego's route."""
    t0 = int(scenario.stamps_ns[0])
    bag.set_custom_data(SCENARIO_KEY, scenario.name)
    if scenario.object_uuids:  # in the metadata: the messages, and so the bag's digest, are the same without it
        bag.set_custom_data(UUIDS_KEY, json.dumps({str(i): uuid for i, uuid in sorted(scenario.object_uuids.items())}))
    bag.write(LANES, t0, msgs.lanes_to_markers(scenario.lanes, t0))
    route = scenario.route
    headings = route.heading(route.stations)
    bag.write(ROUTE, t0, cdr.encode_path(route.points[:, 0], route.points[:, 1], headings, [t0] * len(route.points), t0))


def write_scenario(bag: BagWriter, scenario: Scenario) -> None:
    """A ground-truth bag: static topics, the ego's start, then per frame clock and objects."""
    t0 = int(scenario.stamps_ns[0])
    write_scenario_static(bag, scenario)
    bag.write(ODOMETRY, t0, msgs.ego_to_cdr(scenario.ego_start, t0))
    for k, ns_time in enumerate(scenario.stamps_ns):
        bag.write(CLOCK, int(ns_time), cdr.encode_clock(int(ns_time)))
        bag.write(GROUND_TRUTH, int(ns_time), cdr.encode_objects(scenario.agents.frame(k), int(ns_time), "ground_truth"))


def write_ground_truth_bag(path: Path, scenario: Scenario) -> None:
    with open_bag_for_writing(path) as bag:
        write_scenario(bag, scenario)


def _one_line(exc: BaseException) -> str:
    """An exception's text on one line (YAML and rosbags errors span several)."""
    return " ".join(str(exc).split())


class _Contents(NamedTuple):
    messages: dict[str, list[tuple[int, bytes]]]  # wanted topic -> (log time, CDR payload), in log-time order
    topics: dict[str, tuple[str | None, int]]  # every topic of the bag -> (type, None if its connections differ; count)
    wrong: dict[str, str]  # wanted topic of another type than the contract's -> the problem (its messages left out)


def _read(path: Path, topics: Iterable[str]) -> _Contents:
    """The payloads of the given topics and the bag's topic list; a BagError if it cannot be read."""
    path = Path(path)
    if not path.exists():
        raise BagError(f"{path}: no such bag")
    wanted = set(topics)
    messages: dict[str, list[tuple[int, bytes]]] = {topic: [] for topic in wanted}
    wrong: dict[str, str] = {}
    try:
        with Reader(path) as reader:
            listing = {name: (info.msgtype, info.msgcount) for name, info in reader.topics.items()}
            connections = []
            for connection in reader.connections:
                if connection.topic not in wanted:
                    continue
                expected = TOPIC_TYPES.get(connection.topic)
                if expected is not None and connection.msgtype != expected:
                    wrong[connection.topic] = (f"{path}: topic '{connection.topic}' has type {connection.msgtype!r}, "
                                               f"expected '{expected}'")
                else:
                    connections.append(connection)
            # an empty connection list means "all connections" to rosbags
            for connection, log_time, data in reader.messages(connections=connections) if connections else ():
                messages[connection.topic].append((log_time, bytes(data)))
    except Exception as exc:  # rosbags raises several types for unreadable bags
        raise BagError(f"{path}: not a readable rosbag2 bag: {_one_line(exc)}") from exc
    return _Contents(messages, listing, wrong)


def bag_topics(path: Path) -> dict[str, tuple[str | None, int]]:
    """Every topic of a bag -> (its type, None if its connections differ; its message count)."""
    return _read(path, ()).topics


def read_topics(path: Path, topics: Iterable[str], raw: bool = False
                ) -> tuple[dict[str, list[tuple[int, Any]]], dict[str, str]]:
    """Messages of the given topics in log-time order, as (log time, message), and the bag's
    custom metadata. Messages are deserialised, or with `raw` their CDR bytes as stored."""
    contents = _read(path, topics)
    if contents.wrong:
        raise BagError(next(iter(contents.wrong.values())))
    out: dict[str, list[tuple[int, Any]]] = contents.messages
    if not raw:
        out = {topic: [(log_time, _deserialize(data, contents.topics[topic][0], f"{path}: topic '{topic}'"))
                       for log_time, data in items] for topic, items in out.items()}
    return out, _custom_data(Path(path))


def _deserialize(data: bytes, msgtype: str | None, where: str):
    """A CDR payload as a rosbags message; a BagError naming `where` if it is not one."""
    if msgtype is None:
        raise BagError(f"{where}: its connections differ in message type")
    try:
        return msgs.TYPESTORE.deserialize_cdr(data, msgtype)
    except Exception as exc:  # rosbags raises several types for malformed CDR
        raise BagError(f"{where}: not a valid {msgtype}: {_one_line(exc)}") from None


def _custom_data(path: Path) -> dict[str, str]:
    """The bag's metadata custom_data (rosbags' Reader does not expose it)."""
    metadata = path / "metadata.yaml" if path.is_dir() else path.with_name("metadata.yaml")
    try:
        info = yaml.safe_load(metadata.read_text())["rosbag2_bagfile_information"]
    except (OSError, KeyError, TypeError, yaml.YAMLError):
        return {}
    custom = (info.get("custom_data") if isinstance(info, dict) else None) or {}
    if not isinstance(custom, dict):
        raise BagError(f"{metadata}: field 'custom_data' must be a mapping, not a {type(custom).__name__}")
    return {str(k): str(v) for k, v in custom.items()}


def objects_sequence(frames: list[tuple[int, dict[str, np.ndarray]]]) -> tuple[np.ndarray, BoxSequence]:
    """Frames of objects, in the order given, as (stamps (F,), BoxSequence with one slot per id)."""
    stamps = np.array([s for s, _ in frames], dtype=np.int64)
    ids = np.unique(np.concatenate([f["ids"] for _, f in frames])) if frames else np.zeros(0, np.int64)
    boxes = BoxSequence.empty(len(frames), len(ids))
    for k, (_, frame) in enumerate(frames):
        slots = np.searchsorted(ids, frame["ids"])
        boxes.valid[k, slots] = True
        boxes.ids[k, :] = ids
        for name, values in frame.items():
            if name != "ids":
                getattr(boxes, name)[k, slots] = values
    return stamps, boxes


def _objects(messages: list[tuple[int, bytes]], where: str) -> tuple[np.ndarray, BoxSequence]:
    """Object MarkerArrays in log-time order as (header stamps, boxes with one slot per id). The
    contract: header stamps strictly increase in log-time order (frames out of order are an
    error, not re-sorted) and an id is one object per frame (`cdr.decode_objects`)."""
    frames = []
    for k, (log_time, data) in enumerate(messages):
        stamp, objects = cdr.decode_objects(data, f"{where}, frame {k}")
        if stamp is None and log_time > np.iinfo(np.int64).max:  # no marker: the log time (uint64) stands in
            raise BagError(f"{where}, frame {k}: field 'header.stamp' is missing and the log time {log_time} ns is too late")
        frames.append((log_time if stamp is None else stamp, objects))
    stamps, boxes = objects_sequence(frames)
    back = np.flatnonzero(np.diff(stamps) <= 0)
    if back.size:
        k = int(back[0]) + 1
        raise BagError(f"{where}, frame {k}: field 'header.stamp' ({stamps[k]} ns) is not after frame {k - 1}'s "
                       f"({stamps[k - 1]} ns): frames must be in stamp order, one per stamp")
    return stamps, boxes


def _decode(contents: _Contents, path: Path, topic: str, decode: Callable[[list[tuple[int, bytes]], str], Any]):
    """decode(the topic's messages, where), a missing topic or a MessageError as a BagError."""
    where = f"{path}: topic '{topic}'"
    if topic in contents.wrong:
        raise BagError(contents.wrong[topic])
    if not contents.messages[topic]:
        raise BagError(f"{where} is missing or empty")
    try:
        return decode(contents.messages[topic], where)
    except MessageError as exc:
        raise BagError(str(exc)) from None


def read_objects(path: Path, topic: str) -> tuple[np.ndarray, BoxSequence]:
    """One object topic of a bag: (header stamps, boxes with one slot per object id)."""
    stamps, boxes = _decode(_read(path, [topic]), Path(path), topic, _objects)
    bad = boxes.first_invalid_field()
    if bad is not None:
        name, k, j = bad
        raise BagError(f"{path}: topic '{topic}', frame {k}: field '{name}' of object {int(boxes.ids[k, j])} "
                       f"is not a valid number ({getattr(boxes, name)[k, j]}; every field finite and within "
                       f"{MAGNITUDE_BOUND:g}, sizes positive)")
    return stamps, boxes


def _polyline(points: np.ndarray, where: str) -> Polyline:
    """A route or lane centreline: at least two distinct points, all finite and within the bound every
    coordinate has (beyond it, the segment lengths overflow before any check could name the field)."""
    if not np.all(np.abs(points) <= MAGNITUDE_BOUND):
        raise BagError(f"{where} is not finite (or beyond {MAGNITUDE_BOUND:g} m)")
    try:
        return Polyline(points)
    except ValueError:
        raise BagError(f"{where} needs at least two distinct points") from None


def _ego(messages: list[tuple[int, bytes]], where: str) -> EgoState:
    """The ego's start: one message. More would be a drive (an attack bag's ego, a recording), whose
    first message is not obviously the start a user meant; `advperc import-bag` turns a drive into one."""
    if len(messages) != 1:
        raise BagError(f"{where} holds {len(messages)} messages; a ground-truth bag holds the ego's start only "
                       "(one message): an attack bag or a recorded drive? import a drive with advperc import-bag")
    return msgs.ego_from_cdr(messages[0][1], where)[1]


def route_of(messages: list[tuple[int, bytes]], where: str) -> Polyline:
    """The route a bag's /ego/route holds (its first message)."""
    return _polyline(cdr.decode_path(messages[0][1], where)[1][:, :2], f"{where}: field 'poses'")


def lanes_of(messages: list[tuple[int, bytes]], where: str) -> tuple[Lane, ...]:
    """The lanes a bag's /map/lanes holds (its first message)."""
    markers = _deserialize(messages[0][1], TOPIC_TYPES[LANES], where)
    return tuple(Lane(id=name, centerline=_polyline(points, f"{where}: field 'points' of lane {name!r}"), width=width)
                 for name, points, width in msgs.markers_to_lanes(markers))


class GroundTruthCheck(NamedTuple):
    """A ground-truth bag checked against the contract: every problem at once, each naming the bag and
    the topic or field, so a user fixes a bag in one pass instead of one error at a time."""

    scenario: Scenario | None  # None when there is any problem
    topics: dict[str, tuple[str | None, int]]  # every topic of the bag -> (type, None if its connections differ; count)
    problems: list[str]  # one line each, naming the bag, the topic or field, the frame


def _object_uuids(text: str | None, path: Path) -> dict[int, str]:
    """The custom data UUIDS_KEY of a bag: agent id -> 32 hex digits; a BagError naming the field otherwise."""
    if text is None:
        return {}
    try:
        table = json.loads(text)
        uuids = {int(i): str(uuid) for i, uuid in table.items()}
    except (ValueError, AttributeError, TypeError) as exc:
        raise BagError(f"{path}: field 'custom_data.{UUIDS_KEY}' is not a mapping of agent ids to UUIDs: {exc}") from None
    bad = next((uuid for uuid in uuids.values() if len(uuid) != 32 or any(c not in "0123456789abcdef" for c in uuid)), None)
    if bad is not None:
        raise BagError(f"{path}: field 'custom_data.{UUIDS_KEY}' holds {bad!r}, not a UUID of 32 hex digits")
    return uuids


def check_ground_truth(path: Path) -> GroundTruthCheck:
    """A ground-truth bag against the contract: /ground_truth/objects (at least two frames,
    uniformly stamped, in stamp order, ids unique per frame, finite values, positive sizes),
    /ego/odometry (the ego's start) and /ego/route, each of its type; /map/lanes if present; every
    other topic of the contract it holds (/clock, ...) of the contract's type. Every
    topic is checked, so all their problems are found at once; the Scenario they make is then
    validated. A bag that cannot be read at all raises a BagError."""
    path = Path(path)
    contents = _read(path, [GROUND_TRUTH, ODOMETRY, ROUTE, LANES])
    problems: list[str] = []
    parts: dict[str, Any] = {}  # topic -> what its decoder returns
    for topic, decode in ((GROUND_TRUTH, _objects), (ODOMETRY, _ego), (ROUTE, route_of), (LANES, lanes_of)):
        if topic == LANES and not contents.messages[LANES] and LANES not in contents.wrong:
            parts[LANES] = ()  # the map is optional
            continue
        try:
            parts[topic] = _decode(contents, path, topic, decode)
        except BagError as exc:
            problems.append(str(exc))
    for topic, (msgtype, _) in sorted(contents.topics.items()):  # every contract topic the bag has, of its type:
        expected = TOPIC_TYPES.get(topic)  # a wrong /clock failed the report's digest, after the whole search
        if expected is not None and msgtype != expected and topic not in contents.wrong:
            problems.append(f"{path}: topic '{topic}' has type {msgtype!r}, expected '{expected}'")
    uuids: dict[int, str] = {}
    try:
        custom = _custom_data(path)
        name = custom.get(SCENARIO_KEY, path.name)
        uuids = _object_uuids(custom.get(UUIDS_KEY), path)
    except BagError as exc:
        problems.append(str(exc))
    if problems:
        return GroundTruthCheck(None, contents.topics, problems)
    stamps, agents = parts[GROUND_TRUTH]
    scenario = Scenario(name=name, stamps_ns=stamps, agents=agents, lanes=parts[LANES], route=parts[ROUTE],
                        ego_start=parts[ODOMETRY], object_uuids=uuids)
    problems = scenario.problems(str(path))
    return GroundTruthCheck(None if problems else scenario, contents.topics, problems)


def read_scenario(path: Path) -> Scenario:
    """A ground-truth bag (section 4 of the design) as a Scenario, validated; a BagError names
    the first problem `check_ground_truth` finds."""
    check = check_ground_truth(path)
    if check.problems:
        raise BagError(check.problems[0])
    assert check.scenario is not None  # no problem: check_ground_truth made one
    return check.scenario


def aligned_objects(ground_truth: Path, perceived: Path, topic: str) -> tuple[BoxSequence, BoxSequence, np.ndarray]:
    """(truth, perceived, ego_xy) on the frames both bags share; the 50 m range uses /ego/odometry
    of the perceived bag, else of the ground-truth bag (latest pose at or before each frame): what
    `advperc score` scores and `advperc pem fit` fits to."""
    gt_stamps, truth = read_objects(ground_truth, GROUND_TRUTH)
    pred_stamps, boxes = read_objects(perceived, topic)
    common = np.intersect1d(gt_stamps, pred_stamps)
    if common.size == 0:
        raise BagError(f"{perceived}: topic '{topic}' shares no header.stamp with {ground_truth}")
    odometry = []
    for source in (perceived, ground_truth):
        odometry = read_topics(source, [ODOMETRY])[0][ODOMETRY]
        if odometry:
            break
    if not odometry:
        raise BagError(f"{perceived}: topic '{ODOMETRY}' is missing in both bags (needed for the 50 m range)")
    odo_stamps = np.array([msgs.stamp_ns(m.header.stamp) for _, m in odometry])
    odo_xy = np.array([[msgs.odometry_to_ego(m).x, msgs.odometry_to_ego(m).y] for _, m in odometry])
    latest = np.clip(np.searchsorted(odo_stamps, common, side="right") - 1, 0, len(odometry) - 1)
    boxes = boxes.select(np.searchsorted(pred_stamps, common))
    if np.any(np.isnan(boxes.score[boxes.valid])):
        raise BagError(f"{perceived}: topic '{topic}': field 'text' (confidence) is empty on some markers")
    return truth.select(np.searchsorted(gt_stamps, common)), boxes, odo_xy[latest]
