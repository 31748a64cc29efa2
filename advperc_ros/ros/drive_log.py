"""A team's own recorded drive (a rosbag2 log) -> a Scenario to attack (then a ground-truth bag).

What is read, and what it becomes:

- **Objects**: one topic of any type an interface profile speaks (Autoware's `PredictedObjects`,
  `TrackedObjects`, `DetectedObjects`, `vision_msgs/Detection3DArray`, our `MarkerArray`), read by
  that profile's own decoder. The recorded objects are the ground truth: whatever the team's
  perception saw in that drive is what the attack perturbs. Each message is placed at its header
  stamp.
- **Ego**: a `nav_msgs/Odometry` topic; the ego starts where and as fast as it was at the first
  frame (pose interpolated, speed `twist.linear.x`).
- **Frames**: resampled to a fixed period `dt` from the first stamp both topics have to the last.
  An object is in frame k when the messages just before and just after t_k both hold it (or one
  is stamped t_k exactly); its box is interpolated linearly between them (heading the short way
  round), so a log recorded at the frame times reads back exactly.
- **Road**: the log's own `/map/lanes` and `/ego/route` (the graph's types) when it has them; else the
  route is the recorded ego path, extended straight ahead by `ROUTE_EXTENSION` m, and the lanes a
  corridor: the route itself and `SIDE_LANES` lanes of `LANE_WIDTH` either side of it. A
  recorded lane change is then a drift inside that corridor, not a change of lanes.

Every refusal is a BagError naming the log, the topic and the field, raised before anything is
written: no objects or odometry topic (or several of equal rank and none chosen), a topic of
another type, fewer than two frames, stamps out of order, a field not finite.
"""

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from advperc_ros.core.boxes import BOX_FIELDS, MAGNITUDE_BOUND
from advperc_ros.core.geometry import Polyline
from advperc_ros.core.rules.verdict import AT_FAULT_RULE
from advperc_ros.core.scenario import MAX_PERIOD_NS, MIN_PERIOD_NS, EgoState, Lane, Scenario
from advperc_ros.exceptions import BagError, MessageError
from advperc_ros.ros import bag as bags
from advperc_ros.ros import cdr
from advperc_ros.ros.interfaces.base import Objects, ObjectsLayer
from advperc_ros.ros.interfaces.registry import BUNDLED, load_profile
from advperc_ros.ros.topics import LANES, ROUTE, TOPIC_TYPES

ODOMETRY_TYPE = "nav_msgs/msg/Odometry"
ODOMETRY_TOPICS = ("/localization/kinematic_state", "/ego/odometry")  # preferred, in order, when several
LANE_WIDTH = 3.5  # m
SIDE_LANES = 1
ROUTE_EXTENSION = 300.0  # m beyond the recorded path: a faster ego must not run off its route
ROUTE_SPACING = 0.5  # m: recorded positions closer than this to the last route point are not route points
MAX_FRAMES = 100_000
MIN_DT, MAX_DT = MIN_PERIOD_NS / 1e9, MAX_PERIOD_NS / 1e9  # s: the periods a scenario may have
OUR_UUID_TAIL = "00" * 8  # a UUID of our layout: an id in its first 8 bytes, the rest zero (interfaces/autoware.py)


def object_layers() -> dict[str, ObjectsLayer]:
    """Every objects type a bundled profile speaks -> its layer (the profiles' own: one reading), in
    the order of their layers' `import_rank`: when a log holds several objects topics, what the planner
    saw first (predictions, tracks), detections last."""
    profiles = [load_profile(name) for name in BUNDLED]
    layers = sorted((layer for profile in profiles for layer in (profile.detections, profile.tracks)),
                    key=lambda layer: layer.import_rank)
    out: dict[str, ObjectsLayer] = {}
    for layer in layers:
        out.setdefault(layer.msgtype, layer)
    return out


def _numbered_by_uuid(frames: list[tuple[int, Objects]], uuids: list[dict[int, str]]
                      ) -> tuple[list[tuple[int, Objects]], dict[int, str]]:
    """The frames with their objects numbered 1..n by UUID, in order of first appearance (a frame's new
    ones in UUID order), and each number's UUID: a log's random UUIDs as ids that fit every message type
    and reproduce on every import. A log of our own UUIDs keeps the ids they hold."""
    table = {uuid: object_id for frame in uuids for object_id, uuid in frame.items()}
    if all(uuid.endswith(OUR_UUID_TAIL) for uuid in table):  # ids of ours (an id in the first 8 bytes)
        return frames, {object_id: uuid for uuid, object_id in table.items()}
    number: dict[str, int] = {}
    out = []
    for (stamp, objects), frame_uuids in zip(frames, uuids):
        for uuid in sorted(frame_uuids[int(i)] for i in objects["ids"]):
            number.setdefault(uuid, len(number) + 1)
        ids = np.array([number[frame_uuids[int(i)]] for i in objects["ids"]], dtype=np.int64)
        order = np.argsort(ids, kind="stable")
        out.append((stamp, {**{name: values[order] for name, values in objects.items() if name != "ids"},
                            "ids": ids[order]}))
    return out, {object_id: uuid for uuid, object_id in number.items()}


@dataclass(frozen=True)
class ImportedDrive:
    """A recorded drive as a scenario, with what was read from where (for the command's one line)."""

    scenario: Scenario
    objects_topic: str
    odometry_topic: str
    road: str  # where the lanes and route came from
    target_speed: float  # m/s: the recorded ego's 95th-percentile speed, the planner's cruise speed

    def params(self, bag: str, planner: str) -> dict:
        """The params document of an attack on this drive's bag with `planner`: its target speed, and
        only at-fault collisions counted (recorded traffic does not react to the ego)."""
        return {"orchestrator": {"ros__parameters": {
            "bag": bag, "planner": planner, "planner_params": {"target_speed": round(self.target_speed, 3)},
            "objective": "nds_t", "seed": 0, "rule": {"name": AT_FAULT_RULE}}}}


def _choose(path: Path, listing: dict[str, tuple[str | None, int]], given: str | None, kinds: tuple[str, ...],
            preferred: tuple[str, ...], what: str, flag: str, besides: tuple[str, ...] = ()) -> str:
    """The topic to read: the one given (it must be of one of `kinds`), else the only one of the
    best-ranked kind present (by `preferred` names among several), never one of `besides` (the road's
    topics, whose MarkerArray is no objects topic)."""
    chosen = given
    if given is not None:
        if given not in listing:
            raise BagError(f"{path}: topic '{given}' is not in the log (its topics: {', '.join(sorted(listing))})")
        if listing[given][0] not in kinds:
            raise BagError(f"{path}: topic '{given}' has type {listing[given][0]!r}, not one of {', '.join(kinds)}")
    for kind in kinds if given is None else ():
        found = sorted(topic for topic, (msgtype, _) in listing.items() if msgtype == kind and topic not in besides)
        named = [topic for topic in preferred if topic in found]
        if len(found) > 1 and not named:
            raise BagError(f"{path}: several {what} topics of type {kind} ({', '.join(found)}): choose one with {flag}")
        if found:
            chosen = named[0] if named else found[0]
            break
    if chosen is None:
        raise BagError(f"{path}: no {what} topic (a topic of type {' or '.join(kinds)}); the log's topics: "
                       f"{', '.join(sorted(listing)) or 'none'}")
    if not listing[chosen][1]:
        raise BagError(f"{path}: topic '{chosen}' holds no messages")
    return chosen


def _odometry(messages: list[tuple[int, bytes]], where: str) -> tuple[list[int], np.ndarray]:
    """(stamps in ns, (M, 4) x, y, yaw, speed) of the odometry messages."""
    stamps, rows = [], []
    for k, (_, data) in enumerate(messages):
        try:
            stamp, state = cdr.decode_odometry(data, f"{where}, message {k}")
        except MessageError as exc:
            raise BagError(str(exc)) from None
        stamps.append(stamp)
        rows.append(state)
    table = np.array(rows, dtype=float).reshape(-1, 4)
    bad = np.flatnonzero(~np.all(np.abs(table) <= MAGNITUDE_BOUND, axis=1))
    if bad.size:
        raise BagError(f"{where}, message {int(bad[0])}: field 'pose' or 'twist' is not a valid number")
    _in_order(stamps, where)
    return stamps, table


def _in_order(stamps: list[int], where: str) -> None:
    back = np.flatnonzero(np.diff(np.asarray(stamps, dtype=np.int64)) <= 0)
    if back.size:
        k = int(back[0]) + 1
        raise BagError(f"{where}, message {k}: field 'header.stamp' ({stamps[k]} ns) is not after message {k - 1}'s "
                       f"({stamps[k - 1]} ns): one message per stamp, in stamp order")


def _angle_between(a: float, b: float, w: float) -> float:
    return a + w * ((b - a + math.pi) % (2 * math.pi) - math.pi)


def _sample_odometry(stamps: list[int], table: np.ndarray, t: int) -> tuple[float, float, float, float]:
    j = int(np.searchsorted(stamps, t, side="right")) - 1
    if stamps[j] == t or j == len(stamps) - 1:
        x, y, yaw, speed = table[j].tolist()
        return x, y, yaw, speed
    w = (t - stamps[j]) / (stamps[j + 1] - stamps[j])
    a, b = table[j], table[j + 1]
    return (a[0] + w * (b[0] - a[0]), a[1] + w * (b[1] - a[1]), _angle_between(a[2], b[2], w), a[3] + w * (b[3] - a[3]))


def _sample_objects(frames: list[tuple[int, Objects]], t: int) -> Objects:
    """The objects at time t: those of the message stamped t, or those held by the messages either
    side of t, interpolated."""
    stamps = [stamp for stamp, _ in frames]
    j = int(np.searchsorted(stamps, t, side="right")) - 1
    before_stamp, before = frames[j]
    if before_stamp == t:
        return before
    after_stamp, after = frames[j + 1]
    common, i, k = np.intersect1d(before["ids"], after["ids"], assume_unique=True, return_indices=True)
    w = (t - before_stamp) / (after_stamp - before_stamp)
    out = {name: before[name][i] + w * (after[name][k] - before[name][i]) for name in BOX_FIELDS}
    out["yaw"] = np.array([_angle_between(a, b, w) for a, b in zip(before["yaw"][i], after["yaw"][k])])
    out["score"] = before["score"][i]
    out["ids"] = common
    return out


def _route_from_path(xy: np.ndarray, where: str) -> Polyline:
    points = [xy[0]]
    for point in xy[1:]:
        if np.hypot(*(point - points[-1])) >= ROUTE_SPACING:
            points.append(point)
    if len(points) < 2:
        raise BagError(f"{where}: the recorded ego moves less than {ROUTE_SPACING} m, so its path gives no route: "
                       f"record /ego/route (nav_msgs/Path) in the log")
    heading = np.asarray(points[-1]) - np.asarray(points[-2])
    points.append(points[-1] + heading / np.hypot(*heading) * ROUTE_EXTENSION)
    return Polyline(np.array(points))


def _corridor(route: Polyline) -> tuple[Lane, ...]:
    """The route as a lane, and SIDE_LANES lanes of LANE_WIDTH either side (offset along each vertex's normal)."""
    points = route.points
    tangents = np.gradient(points, axis=0)
    normals = np.stack([-tangents[:, 1], tangents[:, 0]], axis=1) / np.hypot(*tangents.T)[:, None]
    lanes = [Lane("route", route, LANE_WIDTH)]
    for i in range(1, SIDE_LANES + 1):
        lanes += [Lane(f"left{i}", Polyline(points + normals * LANE_WIDTH * i), LANE_WIDTH),
                  Lane(f"right{i}", Polyline(points - normals * LANE_WIDTH * i), LANE_WIDTH)]
    return tuple(lanes)


def import_drive(path: str | Path, objects_topic: str | None = None, odometry_topic: str | None = None,
                 dt: float = 0.1, name: str | None = None) -> ImportedDrive:
    """Read a recorded drive as the module docstring says; a BagError naming the problem otherwise."""
    path = Path(path)
    if not MIN_DT <= dt <= MAX_DT:  # also NaN; a period of 1e-12 s rounded to 0 ns, one of 1e300 s overflowed
        raise BagError(f"{path}: the frame period --dt must be between {MIN_DT:g} and {MAX_DT:g} s, got {dt}")
    listing = bags.bag_topics(path)
    layers = object_layers()
    objects_topic = _choose(path, listing, objects_topic, tuple(layers), (), "objects",
                            "--objects", besides=(LANES,))
    odometry_topic = _choose(path, listing, odometry_topic, (ODOMETRY_TYPE,), ODOMETRY_TOPICS, "odometry",
                             "--odometry")
    road = [topic for topic in (LANES, ROUTE) if listing.get(topic, (None, 0))[0] == TOPIC_TYPES[topic]]
    wanted = [objects_topic, odometry_topic, *road]
    messages, _ = bags.read_topics(path, wanted, raw=True)
    where = f"{path}: topic '{objects_topic}'"
    layer = layers[listing[objects_topic][0] or ""]
    frames, uuids = [], []
    for k, (log_time, data) in enumerate(messages[objects_topic]):
        try:
            stamp, objects = layer.decode(data, f"{where}, message {k}")
            if layer.uuids is not None:
                uuids.append(layer.uuids(data, f"{where}, message {k}"))
        except MessageError as exc:
            raise BagError(str(exc)) from None
        frames.append((log_time if stamp is None else stamp, objects))
    _in_order([stamp for stamp, _ in frames], where)
    object_uuids: dict[int, str] = {}
    if layer.uuids is not None:
        frames, object_uuids = _numbered_by_uuid(frames, uuids)
    odometry_stamps, odometry = _odometry(messages[odometry_topic], f"{path}: topic '{odometry_topic}'")
    first = max(frames[0][0], odometry_stamps[0]) if frames and odometry_stamps else 0
    last = min(frames[-1][0], odometry_stamps[-1]) if frames and odometry_stamps else -1
    step = int(round(dt * 1e9))
    count = (last - first) // step + 1 if last >= first else 0
    if count < 2:
        raise BagError(f"{path}: topics '{objects_topic}' and '{odometry_topic}' overlap for less than two frames of "
                       f"{dt:g} s")
    if count > MAX_FRAMES:
        raise BagError(f"{path}: {count} frames of {dt:g} s, more than {MAX_FRAMES}: cut the log or take a longer period")
    stamps = first + step * np.arange(count, dtype=np.int64)
    _, agents = bags.objects_sequence([(int(t), _sample_objects(frames, int(t))) for t in stamps])
    bad = agents.first_invalid_field()
    if bad is not None:
        field, k, j = bad
        raise BagError(f"{where}, frame {k}: field '{field}' of object {int(agents.ids[k, j])} is not a valid number "
                       f"(every field finite and within {MAGNITUDE_BOUND:g}, sizes positive)")
    start = EgoState(*map(float, _sample_odometry(odometry_stamps, odometry, int(stamps[0]))))
    try:
        lanes = bags.lanes_of(messages[LANES], f"{path}: topic '{LANES}'") if LANES in road else ()
        route = bags.route_of(messages[ROUTE], f"{path}: topic '{ROUTE}'") if ROUTE in road else None
    except MessageError as exc:
        raise BagError(str(exc)) from None
    if route is None:
        route = _route_from_path(odometry[:, :2], f"{path}: topic '{odometry_topic}'")
    if not lanes:
        lanes = _corridor(route)
    source = "the log's " + " and ".join(road) if road else "a corridor around the recorded ego path"
    present = set(np.unique(agents.ids[agents.valid]).tolist())
    scenario = Scenario(name=name or path.name, stamps_ns=stamps, agents=agents, lanes=tuple(lanes), route=route,
                        ego_start=start, object_uuids={i: uuid for i, uuid in object_uuids.items() if i in present})
    scenario.validate(str(path))
    speed = float(np.percentile(odometry[:, 3], 95))
    return ImportedDrive(scenario, objects_topic, odometry_topic, source, max(speed, 1.0))
