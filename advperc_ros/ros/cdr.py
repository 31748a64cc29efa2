"""The per-frame messages of the topic contract as CDR bytes, packed from and read into numpy.

Every frame the graph nodes exchange object MarkerArrays, odometry, a clock, the rule value (a
Float64 and a DiagnosticArray) and a plan (a nav_msgs/Path of some 80 poses). Going through
rosbags message objects costs 0.2 to 0.9 ms per MarkerArray or Path (thousands of small Python
objects built, serialised, decoded and read), more
than a whole embedded IDM frame; packing the bytes straight from the arrays, or reading the arrays
straight out of the bytes, costs a tenth of that. The bytes are exactly rosbags' (and so ROS
2's): plain CDR, little endian (encapsulation 00 01 00 00), zero padding, alignment counted from
the end of the encapsulation header. The rosbags-object factories in `messages` are built on
these codecs, so the convention below is written once; test_cdr holds the bytes to rosbags',
test_dds to Cyclone's. The codecs are tuned for a node's callback, which starts with cold caches
after the other processes of the graph ran: few numpy calls, one struct call where possible.

Object convention (one MarkerArray per frame, frame `map`): the first marker is DELETEALL and
carries the stamp; then per object a CUBE in namespace `objects` (id = agent or track id, pose =
centre and yaw, scale = length, width, height, text = detection confidence as a decimal string,
empty for ground truth and tracks) and an ARROW with the same id in namespace `velocity` whose
points are [centre, centre + velocity x 1 s]. A dropped object is simply absent.

Encoders write that convention; decoders read any valid message of the type (other strings,
colours, textures, meshes, or big endian through rosbags), since external nodes publish too.
"""

import functools
import math
import struct
from collections.abc import Mapping
from typing import Any, NamedTuple, overload

import numpy as np
from numpy.typing import ArrayLike
from rosbags.serde import SerdeError
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from advperc_ros.exceptions import MessageError

TYPESTORE = get_typestore(Stores.ROS2_JAZZY)  # an interface profile's own types join it (`register_types`)


def register_types(definitions: Mapping[str, str]) -> None:
    """Add a stack's own message types (`.msg` text per `pkg/msg/Type` name) to `TYPESTORE`, so bags,
    these codecs and the bare-DDS transport speak them as rclpy does: what an interface profile whose
    types the Jazzy typestore lacks does as its module loads (`Profile.message_types`)."""
    types: dict[str, Any] = {}
    for name, text in definitions.items():
        types.update(get_types_from_msg(text, name))
    TYPESTORE.register(types)


# a message's CDR as it comes: bytes from rclpy and Cyclone, a memoryview from rosbags' serialize_cdr
Cdr = bytes | memoryview
MARKER_ARRAY = "visualization_msgs/msg/MarkerArray"
PATH = "nav_msgs/msg/Path"
ODOMETRY = "nav_msgs/msg/Odometry"
DIAGNOSTICS = "diagnostic_msgs/msg/DiagnosticArray"
FRAME_ID = "map"
CHILD_FRAME_ID = "base_link"
OBJECTS_NS = "objects"
VELOCITY_NS = "velocity"
ARROW_SCALE = (0.2, 0.4, 0.4)
COLORS = {
    "ground_truth": (1.0, 1.0, 1.0, 0.8),
    "recorded": (0.6, 0.6, 0.6, 0.35),  # the recording reactive agents left, faint beside the ground truth
    "perception": (0.1, 0.8, 0.2, 0.8),
    "tracking": (0.2, 0.4, 1.0, 0.8),
    "lanes": (0.3, 0.3, 0.3, 0.5),
}
_MARKER: Any = TYPESTORE.types["visualization_msgs/msg/Marker"]  # built at run time: its constants are not typed
ARROW, CUBE, ADD, DELETEALL = _MARKER.ARROW, _MARKER.CUBE, _MARKER.ADD, _MARKER.DELETEALL

ENCAPSULATION = b"\x00\x01\x00\x00"  # plain CDR, little endian
_U32 = struct.Struct("<I")
_STAMP = struct.Struct("<iI")  # builtin_interfaces/Time: sec, nanosec
_FLOAT64 = struct.Struct("<d")
_HEADER = struct.Struct("<iII")  # stamp sec, nanosec, then the frame_id string's length
# A Marker from its id: id, type, action, padding to 8 (when the offset after them is 4 mod 8),
# pose (7), scale (3), color, lifetime, frame_locked, padding to 4, the number of points; the
# points then start 8-aligned again. Indexed by that padding's presence.
_MARKER_KIND_BODY = (struct.Struct("<3i10d4fiI?3xI"), struct.Struct("<3i4x10d4fiI?3xI"))
_POINT_PAIR = struct.Struct("<6d")
# Odometry from its 8-aligned pose: pose (7), covariance (36, zero), twist (6), covariance (zero)
_ODOMETRY = struct.Struct("<7d288x6d288x")
_POINT_SIZE = 24
_POSE_SIZE = 56
_IDENTITY = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0)
_NO_ARROW = (0.0,) * 6  # velocity read as zero
_BOX_FIELDS = ("x", "y", "yaw", "vx", "vy", "length", "width", "height", "score")


class Status(NamedTuple):
    """A diagnostic_msgs/DiagnosticStatus, its KeyValues as a dict."""

    level: int
    name: str
    message: str
    hardware_id: str
    values: dict[str, str]


def yaw_quaternion(yaw: np.ndarray | float) -> tuple[np.ndarray | float, np.ndarray | float]:
    """(z, w) of the quaternion of a rotation by `yaw` about z (x = y = 0)."""
    return np.sin(yaw / 2.0), np.cos(yaw / 2.0)


@overload
def quaternion_yaw(x: float, y: float, z: float, w: float) -> float: ...
@overload
def quaternion_yaw(x: np.ndarray | float, y: np.ndarray | float, z: np.ndarray, w: np.ndarray | float) -> np.ndarray: ...
def quaternion_yaw(x: np.ndarray | float, y: np.ndarray | float, z: np.ndarray | float,
                   w: np.ndarray | float) -> np.ndarray | float:
    """The yaw (rotation about z) of a quaternion, or of arrays of them: libm's atan2 for both, so a
    yaw is the same to the bit whichever way it is decoded (numpy's arctan2 may differ from it in the
    last bit, by release and by CPU: numpy 2.4 on AMD EPYC did for 7% of random inputs), and the same
    on every machine (glibc's atan2 is correctly rounded)."""
    sine, cosine = 2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z)
    if isinstance(sine, float):
        return math.atan2(sine, cosine)
    sines, cosines = np.asarray(sine, dtype=float), np.asarray(cosine, dtype=float)
    return np.array([math.atan2(a, b) for a, b in zip(sines.ravel().tolist(), cosines.ravel().tolist())],
                    dtype=float).reshape(sines.shape)


def _string(text: str) -> bytes:
    """A CDR string: length with the terminating NUL, the UTF-8 bytes, the NUL."""
    data = text.encode()
    return _U32.pack(len(data) + 1) + data + b"\0"


def _run(*fields: bytes) -> bytes:
    """4-aligned fields back to back, each padded for the next: valid wherever it starts 4-aligned."""
    return b"".join(field + bytes(-len(field) % 4) for field in fields)


def _strings(*texts: str) -> bytes:
    """CDR strings back to back from a 4-aligned offset (no padding after the last)."""
    fields = [_string(text) for text in texts]
    return _run(*fields[:-1]) + fields[-1]


_EMPTY_STRING = _string("")
_NONE = _U32.pack(0)  # an empty sequence
# Marker fields after `points` up to `text`: colors, texture_resource, texture (header, format,
# data) and uv_coordinates, all empty; then after `text`: mesh_resource, mesh_file and
# mesh_use_embedded_materials (False).
_BEFORE_TEXT = _run(_NONE, _EMPTY_STRING, bytes(8), _EMPTY_STRING, _EMPTY_STRING, _NONE, _NONE)
_AFTER_TEXT = _run(_EMPTY_STRING, _EMPTY_STRING, _NONE) + b"\0"
_OBJECTS_NAME = OBJECTS_NS.encode()
_VELOCITY_NAME = VELOCITY_NS.encode()


def _stamp(ns_time: int) -> bytes:
    return _STAMP.pack(*divmod(int(ns_time), 1_000_000_000))


def _header(ns_time: int) -> bytes:
    """std_msgs/Header stamped `ns_time` in FRAME_ID."""
    return _stamp(ns_time) + _string(FRAME_ID)


@functools.lru_cache(maxsize=1024)
def _marker_layout(offset: int, head: int, points: int, text: int) -> struct.Struct:
    """The CDR of a Marker as the encoders write it, from a body offset of `offset` modulo 8
    (padding to 4 first): header and namespace (`head` bytes, from `_run`), id, type, action,
    padding to 8, pose, scale, color, lifetime, frame_locked, `points` Points, the empty fields
    around `text` (`text` bytes). One struct per layout packs a marker in one call."""
    lead = -offset & 3
    to_pose = -(offset + lead + head + 12) & 7
    after_text = -(text + 1) & 3
    return struct.Struct(f"<{lead}x{head}s3i{to_pose}x10d4fiI?3xI{3 * points}d{len(_BEFORE_TEXT)}s"
                         f"I{text}s{1 + after_text}x{len(_AFTER_TEXT)}s")


def _put_marker(parts: list[bytes], offset: int, head: bytes, kind: tuple[int, int, int], pose_scale: tuple[float, ...],
                color: tuple[float, ...], points: tuple[float, ...] = (), text: bytes = b"") -> int:
    """Append one visualization_msgs/Marker at body offset `offset`; the offset after it. `head`
    is its header and namespace (`_run`), `kind` (id, type, action), `points` their coordinates."""
    layout = _marker_layout(offset & 7, len(head), len(points) // 3, len(text))
    parts.append(layout.pack(head, *kind, *pose_scale, *color, 0, 0, False, len(points) // 3, *points,
                             _BEFORE_TEXT, len(text) + 1, text, _AFTER_TEXT))
    return offset + layout.size


def encode_objects(objects: dict[str, np.ndarray], ns_time: int, kind: str) -> bytes:
    """A frame of boxes (dict of 1-D arrays: ids and core.boxes.BOX_FIELDS) as the CDR of a
    MarkerArray; `kind` picks the colour (COLORS)."""
    header = _header(ns_time)
    delete_all, cube, arrow = (_run(header, _string(ns)) for ns in ("", OBJECTS_NS, VELOCITY_NS))
    color = COLORS[kind]
    parts = [ENCAPSULATION, _U32.pack(1 + 2 * len(objects["ids"]))]
    offset = _put_marker(parts, 4, delete_all, (0, CUBE, DELETEALL), (*_IDENTITY, 0.0, 0.0, 0.0), color)
    x, y, height = objects["x"], objects["y"], objects["height"]
    rows = np.array([x, y, height / 2.0, *yaw_quaternion(objects["yaw"]), objects["length"], objects["width"], height,
                     x + objects["vx"], y + objects["vy"]]).T.tolist()
    for marker_id, score, (x, y, z, qz, qw, length, width, height, tip_x, tip_y) in zip(
            objects["ids"].tolist(), objects["score"].tolist(), rows):
        text = repr(score).encode() if math.isfinite(score) else b""
        offset = _put_marker(parts, offset, cube, (marker_id, CUBE, ADD), (x, y, z, 0.0, 0.0, qz, qw, length, width, height),
                             color, text=text)
        offset = _put_marker(parts, offset, arrow, (marker_id, ARROW, ADD), _IDENTITY + ARROW_SCALE, color,
                             (x, y, z, tip_x, tip_y, z))
    return b"".join(parts)


@functools.lru_cache(maxsize=64)
def _stamped_pose(length: int, start: int) -> np.dtype:
    """The CDR layout of a geometry_msgs/PoseStamped whose frame_id takes `length` bytes (with its
    NUL) and which starts at a body offset of `start` modulo 8: stamp, frame_id (length, bytes),
    padding to 8, pose. A pose ends 8-aligned, so all poses after the first with frame_ids as
    long share one layout: numpy packs and reads them as one record array."""
    pose = ((start + 19 + length) & -8) - start
    return np.dtype({"names": ["sec", "nanosec", "length", "frame_id", "pose"],
                     "formats": ["<i4", "<u4", "<u4", f"V{length}", ("<f8", 7)],
                     "offsets": [0, 4, 8, 12, pose], "itemsize": pose + _POSE_SIZE})


def encode_path(xs: ArrayLike, ys: ArrayLike, yaws: ArrayLike, stamps: ArrayLike, ns_time: int) -> bytes:
    """A nav_msgs/Path's CDR: stamped `ns_time`, pose i at (xs[i], ys[i], 0) with yaw yaws[i],
    stamped stamps[i] (ns), all in FRAME_ID."""
    xs, ys, yaws, stamps = np.asarray(xs), np.asarray(ys), np.asarray(yaws), np.asarray(stamps, dtype=np.int64)
    head = ENCAPSULATION + _run(_header(ns_time)) + _U32.pack(len(stamps))
    parts = [head]
    frame_id = FRAME_ID.encode() + b"\0"
    for run, start in ((slice(0, 1), len(head) - len(ENCAPSULATION)), (slice(1, None), 0)):  # the first, the others
        poses = np.zeros(len(stamps[run]), _stamped_pose(len(frame_id), start & 7))
        poses["sec"], poses["nanosec"] = np.divmod(stamps[run], 1_000_000_000)
        poses["length"], poses["frame_id"] = len(frame_id), np.void(frame_id)
        pose = poses["pose"]
        pose[:, 0], pose[:, 1] = xs[run], ys[run]
        pose[:, 5], pose[:, 6] = yaw_quaternion(yaws[run])
        parts.append(poses.tobytes())
    return b"".join(parts)


def encode_odometry(x: float, y: float, yaw: float, speed: float, ns_time: int) -> bytes:
    """A nav_msgs/Odometry's CDR: stamped `ns_time`, pose (x, y, 0) with `yaw` in FRAME_ID,
    `speed` along the body's x axis (child frame CHILD_FRAME_ID), covariances zero."""
    head = _run(_header(ns_time), _string(CHILD_FRAME_ID))
    z, w = yaw_quaternion(yaw)
    pose_twist = (x, y, 0.0, 0.0, 0.0, z, w, speed, 0.0, 0.0, 0.0, 0.0, 0.0)
    return ENCAPSULATION + head + bytes(-len(head) & 7) + _ODOMETRY.pack(*pose_twist)


def encode_diagnostics(ns_time: int, status: Status) -> bytes:
    """A diagnostic_msgs/DiagnosticArray's CDR: stamped `ns_time` in FRAME_ID, one status."""
    keys_values = [text for pair in status.values.items() for text in pair]
    return (ENCAPSULATION + _run(_header(ns_time)) + _U32.pack(1) + bytes([status.level, 0, 0, 0])
            + _run(_strings(status.name, status.message, status.hardware_id)) + _U32.pack(len(status.values))
            + (_strings(*keys_values) if keys_values else b""))


def encode_clock(ns_time: int) -> bytes:
    """A rosgraph_msgs/Clock's CDR."""
    return ENCAPSULATION + _stamp(ns_time)


def encode_float64(value: float) -> bytes:
    """A std_msgs/Float64's CDR."""
    return ENCAPSULATION + _FLOAT64.pack(value)


def payload(msg: object, msgtype: str) -> bytes:
    """What a publisher sends: `msg` itself if it is a CDR payload already (bytes, as the
    encoders here make), else rosbags' CDR of the message object."""
    return msg if isinstance(msg, bytes) else bytes(TYPESTORE.serialize_cdr(msg, msgtype))


# -- decoding ----------------------------------------------------------------------------------


def header_stamp(data: Cdr, where: str) -> int:
    """The stamp (ns) of any message that begins with a std_msgs/Header (Path, Trajectory, the
    object arrays), without decoding the rest."""
    if len(data) < 12 or data[0] != 0 or data[1] not in (0, 1):
        raise MessageError(f"{where}: not a plain CDR payload with a header (encapsulation {bytes(data[:4]).hex()})")
    sec, nanosec = struct.unpack_from("<iI" if data[1] else ">iI", data, 4)
    return sec * 1_000_000_000 + nanosec


def deserialize(data: Cdr, msgtype: str, where: str) -> Any:
    """A message of any registered type as a rosbags object (either byte order), for the types
    read too rarely or too variously to earn a codec of their own; a payload that is not one is a
    MessageError prefixed by `where`."""
    try:
        return TYPESTORE.deserialize_cdr(data, msgtype)
    except (SerdeError, ValueError, IndexError, struct.error) as exc:
        raise MessageError(f"{where}: not a {msgtype} ({exc})") from None


def _body(data: Cdr, msgtype: str, where: str) -> bytes:
    """The CDR after the encapsulation header, little endian (big endian is re-encoded by rosbags)."""
    if len(data) < 4 or data[0] != 0 or data[1] not in (0, 1):
        raise MessageError(f"{where}: not a plain CDR payload (encapsulation {bytes(data[:4]).hex()})")
    if data[1] == 0:
        try:
            data = TYPESTORE.serialize_cdr(TYPESTORE.deserialize_cdr(data, msgtype), msgtype, little_endian=True)
        except SerdeError as exc:
            raise MessageError(f"{where}: {exc}") from None
    return bytes(data[4:])


def _skip_string(body: bytes, pos: int) -> int:
    pos = (pos + 3) & -4
    return pos + 4 + _U32.unpack_from(body, pos)[0]


def _read_string(body: bytes, pos: int) -> tuple[str, int]:
    pos = (pos + 3) & -4
    end = pos + 4 + _U32.unpack_from(body, pos)[0]
    return body[pos + 4: end - 1].decode(), end


def _skip_sequence(body: bytes, pos: int, item_size: int, item_align: int) -> int:
    pos = (pos + 3) & -4
    count = _U32.unpack_from(body, pos)[0]
    pos += 4
    return ((pos + item_align - 1) & -item_align) + count * item_size if count else pos


def _skip_media(body: bytes, pos: int) -> int:
    """Past a Marker's colors, texture_resource, texture and uv_coordinates, whatever they hold."""
    if body.startswith(_BEFORE_TEXT, pos):  # all empty, as the encoders write them
        return pos + len(_BEFORE_TEXT)
    pos = _skip_sequence(body, pos, 16, 4)  # colors
    pos = _skip_string(body, pos)  # texture_resource
    pos = _skip_string(body, ((pos + 3) & -4) + 8)  # texture: header stamp, frame_id
    pos = _skip_string(body, pos)  # texture.format
    pos = _skip_sequence(body, pos, 1, 1)  # texture.data
    return _skip_sequence(body, pos, 8, 4)  # uv_coordinates


def _skip_mesh(body: bytes, pos: int) -> int:
    """Past a Marker's mesh_resource, mesh_file and mesh_use_embedded_materials."""
    if body.startswith(_AFTER_TEXT, pos):  # as the encoders write them
        return pos + len(_AFTER_TEXT)
    pos = _skip_string(body, _skip_string(body, pos))  # mesh_resource, mesh_file.filename
    return _skip_sequence(body, pos, 1, 1) + 1


def _read_marker(body: bytes, pos: int) -> tuple[tuple, int]:
    """One Marker at body offset `pos`: ((stamp ns, ns, id, action, pose and scale, first two
    points or None, text), end). Alignment is spelled out ((pos + 3) & -4 is the next multiple
    of 4): this runs for every marker of every frame."""
    pos = (pos + 3) & -4
    sec, nanosec, length = _HEADER.unpack_from(body, pos)
    pos = (pos + 15 + length) & -4
    length = _U32.unpack_from(body, pos)[0]
    ns = body[pos + 4: pos + 3 + length]
    pos = (pos + 7 + length) & -4
    layout = _MARKER_KIND_BODY[(pos + 12) & 7 != 0]
    fields = layout.unpack_from(body, pos)
    pos += layout.size
    count = fields[-1]
    points = _POINT_PAIR.unpack_from(body, pos) if count == 2 else None
    pos = _skip_media(body, pos + count * _POINT_SIZE)
    length = _U32.unpack_from(body, pos)[0]
    text = body[pos + 4: pos + 3 + length]
    pos = _skip_mesh(body, (pos + 7 + length) & -4)
    return (sec * 1_000_000_000 + nanosec, ns, fields[0], fields[2], fields[3:13], points, text), pos


def _read_markers(data: Cdr, where: str) -> list[tuple]:
    body = _body(data, MARKER_ARRAY, where)
    try:
        pos, markers = 4, []
        for _ in range(_U32.unpack_from(body, 0)[0]):
            marker, pos = _read_marker(body, pos)
            markers.append(marker)
    except struct.error as exc:
        raise MessageError(f"{where}: a MarkerArray cut short or malformed ({exc})") from None
    if pos > len(body):
        raise MessageError(f"{where}: a MarkerArray cut short")
    return markers


def _score(text: bytes, marker_id: int, where: str) -> float:
    try:
        return float(text.decode()) if text else math.nan
    except ValueError:
        raise MessageError(f"{where}: field 'text' of marker {marker_id} is not a confidence: "
                           f"{text.decode(errors='replace')!r}") from None


def decode_objects(data: Cdr, where: str) -> tuple[int | None, dict[str, np.ndarray]]:
    """The CDR of an object MarkerArray as (its stamp: the first marker's, None if it has no
    marker; the boxes as a dict of 1-D arrays, sorted by id); `where` prefixes any error. An id
    is one object: a second CUBE (or ARROW) with an id already seen is an error, not dropped."""
    markers = _read_markers(data, where)
    cubes: dict[int, tuple] = {}
    arrows: dict[int, tuple] = {}
    for _, ns, marker_id, action, pose_scale, points, text in markers:
        if action == DELETEALL:
            continue
        if ns == _OBJECTS_NAME:
            seen, value = cubes, (pose_scale, text)
        elif ns == _VELOCITY_NAME:
            seen, value = arrows, points
        else:
            continue
        if marker_id in seen:
            raise MessageError(f"{where}: field 'id': object {marker_id} appears twice in namespace '{ns.decode()}'")
        seen[marker_id] = value
    ids = sorted(cubes)
    rows = []
    for marker_id in ids:  # per object in Python: numpy calls cost more than the arithmetic here
        (x, y, _, qx, qy, qz, qw, length, width, height), text = cubes[marker_id]
        tail_x, tail_y, _, tip_x, tip_y, _ = arrows.get(marker_id) or _NO_ARROW
        rows.append((x, y, quaternion_yaw(qx, qy, qz, qw), tip_x - tail_x, tip_y - tail_y, length, width, height,
                     _score(text, marker_id, where)))
    columns = np.array(rows, dtype=float).reshape(-1, len(_BOX_FIELDS)).T.copy()
    objects = dict(zip(_BOX_FIELDS, columns))
    objects["ids"] = np.asarray(ids, dtype=np.int64)
    return (markers[0][0] if markers else None), objects


def decode_odometry(data: Cdr, where: str) -> tuple[int, tuple[float, float, float, float]]:
    """The CDR of a nav_msgs/Odometry as (its stamp, (x, y, yaw, speed along the body's x axis));
    `where` prefixes any error."""
    body = _body(data, ODOMETRY, where)
    try:
        sec, nanosec, length = _HEADER.unpack_from(body, 0)
        pos = (_skip_string(body, 12 + length) + 7) & -8  # past child_frame_id, to the pose
        x, y, _, qx, qy, qz, qw, speed, *_ = _ODOMETRY.unpack_from(body, pos)
    except struct.error as exc:
        raise MessageError(f"{where}: an Odometry cut short ({exc})") from None
    return sec * 1_000_000_000 + nanosec, (x, y, quaternion_yaw(qx, qy, qz, qw), speed)


def _read_status(body: bytes, pos: int) -> tuple[Status, int]:
    """A DiagnosticStatus at body offset `pos` (a byte first: no alignment) and its end."""
    level = body[pos]
    name, pos = _read_string(body, pos + 1)
    message, pos = _read_string(body, pos)
    hardware_id, pos = _read_string(body, pos)
    pos = (pos + 3) & -4
    count = _U32.unpack_from(body, pos)[0]
    pos += 4
    values = {}
    for _ in range(count):
        key, pos = _read_string(body, pos)
        values[key], pos = _read_string(body, pos)
    return Status(level, name, message, hardware_id, values), pos


def decode_diagnostics(data: Cdr, where: str) -> tuple[int, list[Status]]:
    """The CDR of a diagnostic_msgs/DiagnosticArray as (its stamp, its statuses); `where`
    prefixes any error."""
    body = _body(data, DIAGNOSTICS, where)
    try:
        sec, nanosec, length = _HEADER.unpack_from(body, 0)
        pos = (15 + length) & -4
        count = _U32.unpack_from(body, pos)[0]
        pos += 4
        statuses = []
        for _ in range(count):
            status, pos = _read_status(body, pos)
            statuses.append(status)
    except (struct.error, IndexError, UnicodeDecodeError) as exc:
        raise MessageError(f"{where}: a DiagnosticArray cut short or malformed ({exc})") from None
    if pos > len(body):
        raise MessageError(f"{where}: a DiagnosticArray cut short")
    return sec * 1_000_000_000 + nanosec, statuses


def _read_poses(body: bytes, pos: int, count: int, where: str) -> tuple[np.ndarray, np.ndarray]:
    """(stamps (P,) ns, poses (P, 7)) of `count` PoseStamped from body offset `pos`. A pose ends
    8-aligned, so poses whose frame_ids are as long follow each other at one stride and are read
    as one numpy record array: the first pose, then usually all the others in a single run."""
    stamps, poses = [], []
    while count:
        pos = (pos + 3) & -4
        length = min(_U32.unpack_from(body, pos + 8)[0], len(body))  # a bogus length then does not fit
        layout = _stamped_pose(length, pos & 7)
        fit = min(1 if pos & 7 else count, (len(body) - pos) // layout.itemsize)
        if not fit:
            raise MessageError(f"{where}: a Path cut short")
        run = np.ndarray(fit, layout, body, pos)
        same = run["length"] == run["length"][0]
        run = run[: fit if same.all() else int(same.argmin())]
        stamps.append(run["sec"].astype(np.int64) * 1_000_000_000 + run["nanosec"])
        poses.append(run["pose"])
        pos += len(run) * layout.itemsize
        count -= len(run)
    return (np.concatenate(stamps), np.concatenate(poses)) if stamps else (np.zeros(0, np.int64), np.zeros((0, 7)))


def decode_path(data: Cdr, where: str) -> tuple[int, np.ndarray, np.ndarray]:
    """The CDR of a nav_msgs/Path as (header stamp ns; poses (P, 3) as x, y, yaw; pose stamps
    (P,) ns); `where` prefixes any error."""
    body = _body(data, PATH, where)
    try:
        sec, nanosec, length = _HEADER.unpack_from(body, 0)
        pos = (15 + length) & -4
        stamps, pose = _read_poses(body, pos + 4, _U32.unpack_from(body, pos)[0], where)
    except struct.error as exc:
        raise MessageError(f"{where}: a Path cut short or malformed ({exc})") from None
    poses = np.column_stack([pose[:, 0], pose[:, 1], quaternion_yaw(*pose[:, 3:7].T)])
    return sec * 1_000_000_000 + nanosec, poses, stamps
