"""rosbag2 MCAP bags of the topic contract: ground-truth bags in, attack bags out.

Bags are written with rosbags (storage MCAP, metadata version 9, CDR, ros2msg schemas), so `ros2
bag info`, Foxglove and the mcap-ros2-support decoder read them. A bag is written into a hidden
sibling directory and renamed into place once complete: a killed run leaves no bag that looks whole.
"""

import hashlib
import shutil
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from rosbags.rosbag2 import Reader, StoragePlugin, Writer
from rosbags.rosbag2.metadata import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime

from advperc_ros.core.boxes import BoxSequence
from advperc_ros.core.geometry import Polyline
from advperc_ros.core.scenario import Lane, Scenario, ScenarioError
from advperc_ros.ros import cdr
from advperc_ros.ros import messages as msgs
from advperc_ros.ros.topics import CLOCK, GROUND_TRUTH, LANES, LATCHED, ODOMETRY, ROUTE, TOPIC_TYPES, depth

SCENARIO_KEY = "advperc.scenario"
ROS_DISTRO = "jazzy"  # the message definitions come from rosbags' Jazzy typestore


class BagError(ValueError):
    """A bag that cannot be used; the message names the file and the topic or field."""


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
        self._connections: dict[str, object] = {}

    def write(self, topic: str, ns_time: int, message) -> None:
        """Write a rosbags message, or its CDR payload (bytes, as `cdr` encodes it)."""
        if topic not in self._connections:
            self._connections[topic] = self._writer.add_connection(
                topic, TOPIC_TYPES[topic], typestore=msgs.TYPESTORE, offered_qos_profiles=[_qos(topic in LATCHED)]
            )
        self._writer.write(self._connections[topic], int(ns_time), cdr.payload(message, TOPIC_TYPES[topic]))

    def set_custom_data(self, key: str, value: str) -> None:
        self._writer.set_custom_data(key, value)


@contextmanager
def open_bag_for_writing(path: Path) -> Iterator[BagWriter]:
    """A bag directory at `path` (its file is `<name>.mcap` inside), written atomically."""
    path = Path(path)
    if path.exists():
        raise BagError(f"{path}: exists already, not overwriting")
    staging = path.with_name(f".{path.name}.partial")
    if staging.exists():
        shutil.rmtree(staging)
    staging.parent.mkdir(parents=True, exist_ok=True)
    try:
        writer = Writer(staging, version=9, storage_plugin=StoragePlugin.MCAP)
        writer.open()
        try:
            yield BagWriter(writer)
        finally:
            writer.close()
        (staging / f"{staging.name}.mcap").rename(staging / f"{path.name}.mcap")
        _finish_metadata(staging / "metadata.yaml", staging.name, path.name)
        staging.rename(path)
    finally:
        if staging.exists():
            shutil.rmtree(staging)


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


def read_topics(path: Path, topics: Iterable[str], raw: bool = False
                ) -> tuple[dict[str, list[tuple[int, Any]]], dict[str, str]]:
    """Messages of the given topics in log-time order, as (log time, message), and the bag's
    custom metadata. Messages are deserialised, or with `raw` their CDR bytes as stored."""
    path = Path(path)
    if not path.exists():
        raise BagError(f"{path}: no such bag")
    wanted = set(topics)
    out: dict[str, list[tuple[int, Any]]] = {topic: [] for topic in wanted}
    try:
        with Reader(path) as reader:
            connections = [c for c in reader.connections if c.topic in wanted]
            for connection in connections:
                expected = TOPIC_TYPES.get(connection.topic)
                if expected is not None and connection.msgtype != expected:
                    raise BagError(f"{path}: topic '{connection.topic}' has type {connection.msgtype}, expected {expected}")
            # an empty connection list means "all connections" to rosbags
            for connection, log_time, data in reader.messages(connections=connections) if connections else ():
                message = bytes(data) if raw else msgs.TYPESTORE.deserialize_cdr(data, connection.msgtype)
                out[connection.topic].append((log_time, message))
    except BagError:
        raise
    except Exception as exc:  # rosbags raises several types for unreadable bags
        raise BagError(f"{path}: not a readable rosbag2 bag: {exc}") from exc
    return out, _custom_data(path)


def _custom_data(path: Path) -> dict[str, str]:
    """The bag's metadata custom_data (rosbags' Reader does not expose it)."""
    metadata = path / "metadata.yaml" if path.is_dir() else path.with_name("metadata.yaml")
    try:
        info = yaml.safe_load(metadata.read_text())["rosbag2_bagfile_information"]
    except (OSError, KeyError, TypeError, yaml.YAMLError):
        return {}
    return {str(k): str(v) for k, v in (info.get("custom_data") or {}).items()}


def objects_sequence(frames: list[tuple[int, dict[str, np.ndarray]]]) -> tuple[np.ndarray, BoxSequence]:
    """Frames of objects sorted by stamp, as (stamps (F,), BoxSequence with one slot per id)."""
    frames = sorted(frames, key=lambda item: item[0])
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


def read_objects(path: Path, topic: str) -> tuple[np.ndarray, BoxSequence]:
    """One object topic of a bag: (header stamps, boxes with one slot per object id)."""
    messages = read_topics(path, [topic], raw=True)[0][topic]
    if not messages:
        raise BagError(f"{path}: topic '{topic}' is missing or empty")
    where = f"{path}: topic '{topic}'"
    frames = []
    for log_time, data in messages:
        try:
            stamp, objects = cdr.decode_objects(data, where)
        except cdr.MessageError as exc:
            raise BagError(str(exc)) from None
        frames.append((log_time if stamp is None else stamp, objects))
    stamps, boxes = objects_sequence(frames)
    if np.any(np.diff(stamps) <= 0):
        raise BagError(f"{where}: field 'header.stamp' repeats or goes back in time")
    bad = boxes.first_invalid_field()
    if bad is not None:
        name, k, j = bad
        raise BagError(f"{where}: field '{name}' of object {int(boxes.ids[k, j])} at frame {k} is not a valid number")
    return stamps, boxes


def read_scenario(path: Path) -> Scenario:
    """A ground-truth bag (section 4 of the design) as a Scenario, validated."""
    path = Path(path)
    stamps, agents = read_objects(path, GROUND_TRUTH)
    topics, custom = read_topics(path, [ODOMETRY, ROUTE, LANES])
    if not topics[ODOMETRY]:
        raise BagError(f"{path}: topic '{ODOMETRY}' is missing (the ego's start)")
    if not topics[ROUTE]:
        raise BagError(f"{path}: topic '{ROUTE}' is missing")
    route_poses, _ = msgs.path_points(topics[ROUTE][0][1])
    if route_poses.shape[0] < 2 or not np.all(np.isfinite(route_poses)):
        raise BagError(f"{path}: topic '{ROUTE}' needs at least two finite poses")
    lanes = []
    if topics[LANES]:
        for name, points, width in msgs.markers_to_lanes(topics[LANES][0][1]):
            lanes.append(Lane(id=name, centerline=Polyline(points), width=width))
    scenario = Scenario(
        name=custom.get(SCENARIO_KEY, path.name),
        stamps_ns=stamps,
        agents=agents,
        lanes=tuple(lanes),
        route=Polyline(route_poses[:, :2]),
        ego_start=msgs.odometry_to_ego(topics[ODOMETRY][0][1]),
    )
    try:
        scenario.validate(str(path))
    except ScenarioError as exc:
        raise BagError(str(exc)) from exc
    return scenario
