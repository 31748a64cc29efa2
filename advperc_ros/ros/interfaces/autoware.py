"""Autoware's interface: `DetectedObjects` from the detector, `PredictedObjects` to the planner,
`autoware_planning_msgs/Trajectory` back, the ego's `Odometry` on `/localization/kinematic_state`.

Conversions, and where they cannot be exact:

- ids: Autoware names an object by a 16-byte UUID. An id of ours goes out as its int32 in the first
  8 bytes (int64, little endian), the rest zero, and reads back as itself. Any other UUID (a
  tracker's random uuid4, a counter in the low bytes) reads back as a stable id in [2^30, 2^31): 30
  bits of its BLAKE2b digest, within every message type's range (a Marker's id is an int32), so a
  tracker's own UUIDs keep telling objects apart; import-bag numbers a log's objects 1..n instead and
  keeps their UUIDs (`uuids_of`, ros/drive_log.py). `DetectedObject` has no id: detections read back
  numbered 0..n-1, as a detector's boxes are.
- velocity: Autoware's twist is in the object's own frame (x along its heading); ours is in `map`.
  It is rotated on the way out and back (a round trip is exact to within 1e-15 m/s).
- confidence: `existence_probability` is a float32, so a score comes back rounded to float32;
  no node of the graph computes anything from it.
- shape: a bounding box (`dimensions` = length, width, height); a cylinder reads back as a square
  of its diameter, a polygon as the extent of its footprint along the object's axes.
- prediction: each predicted object carries one constant-velocity path (`PREDICTION_HORIZON` s in
  steps of `PREDICTION_STEP` s), the tracker's own motion model, since Autoware's map-based
  prediction needs a Lanelet2 map; classification is CAR with probability 1 (every object of the
  bundled scenarios is a vehicle); covariances are zero (the boxes carry none).
- plan: `time_from_start` carries each point's time, to the nanosecond (exact). Autoware's own
  planners sample by distance, start behind the ego and often leave it 0; such a trajectory is
  timed from its speeds: the ego's foot on the polyline (pose and speed interpolated there) is the
  plan's time, each later segment takes its length over the mean of its two speeds, and where the
  speed falls to zero (`STOPPED_SPEED`) the ego stops and waits at that point.
"""

import hashlib
import math
from collections.abc import Callable
from typing import Any

import numpy as np

from advperc_ros.core.boxes import BOX_FIELDS
from advperc_ros.core.planners.base import Trajectory
from advperc_ros.exceptions import MessageError
from advperc_ros.ros import messages as msgs
from advperc_ros.ros.cdr import TYPESTORE, Cdr, deserialize, quaternion_yaw, register_types
from advperc_ros.ros.interfaces.base import Objects, ObjectsLayer, PlanLayer, Profile, objects_from_rows

AUTOWARE = "autoware_perception_msgs/msg/"
PLANNING = "autoware_planning_msgs/msg/"
MESSAGE_TYPES: dict[str, str] = {
    AUTOWARE + "ObjectClassification": """
uint8 UNKNOWN=0
uint8 CAR=1
uint8 TRUCK=2
uint8 BUS=3
uint8 TRAILER=4
uint8 MOTORCYCLE=5
uint8 BICYCLE=6
uint8 PEDESTRIAN=7
uint8 ANIMAL=8
uint8 HAZARD=9
uint8 OVER_DRIVABLE=10
uint8 UNDER_DRIVABLE=11
uint8 label
float32 probability
""",
    AUTOWARE + "Shape": """
uint8 BOUNDING_BOX=0
uint8 CYLINDER=1
uint8 POLYGON=2
uint8 type
geometry_msgs/Polygon footprint
geometry_msgs/Vector3 dimensions
""",
    AUTOWARE + "DetectedObjectKinematics": """
uint8 UNAVAILABLE=0
uint8 SIGN_UNKNOWN=1
uint8 AVAILABLE=2
geometry_msgs/PoseWithCovariance pose_with_covariance
bool has_position_covariance
uint8 orientation_availability
geometry_msgs/TwistWithCovariance twist_with_covariance
bool has_twist
bool has_twist_covariance
""",
    AUTOWARE + "DetectedObject": """
float32 existence_probability
autoware_perception_msgs/ObjectClassification[] classification
autoware_perception_msgs/DetectedObjectKinematics kinematics
autoware_perception_msgs/Shape shape
""",
    AUTOWARE + "DetectedObjects": """
std_msgs/Header header
autoware_perception_msgs/DetectedObject[] objects
""",
    AUTOWARE + "TrackedObjectKinematics": """
uint8 UNAVAILABLE=0
uint8 SIGN_UNKNOWN=1
uint8 AVAILABLE=2
geometry_msgs/PoseWithCovariance pose_with_covariance
geometry_msgs/TwistWithCovariance twist_with_covariance
geometry_msgs/AccelWithCovariance acceleration_with_covariance
uint8 orientation_availability
bool is_stationary
""",
    AUTOWARE + "TrackedObject": """
unique_identifier_msgs/UUID object_id
float32 existence_probability
autoware_perception_msgs/ObjectClassification[] classification
autoware_perception_msgs/TrackedObjectKinematics kinematics
autoware_perception_msgs/Shape shape
""",
    AUTOWARE + "TrackedObjects": """
std_msgs/Header header
autoware_perception_msgs/TrackedObject[] objects
""",
    AUTOWARE + "PredictedPath": """
geometry_msgs/Pose[] path
builtin_interfaces/Duration time_step
float32 confidence
""",
    AUTOWARE + "PredictedObjectKinematics": """
geometry_msgs/PoseWithCovariance initial_pose_with_covariance
geometry_msgs/TwistWithCovariance initial_twist_with_covariance
geometry_msgs/AccelWithCovariance initial_acceleration_with_covariance
autoware_perception_msgs/PredictedPath[] predicted_paths
""",
    AUTOWARE + "PredictedObject": """
unique_identifier_msgs/UUID object_id
float32 existence_probability
autoware_perception_msgs/ObjectClassification[] classification
autoware_perception_msgs/PredictedObjectKinematics kinematics
autoware_perception_msgs/Shape shape
""",
    AUTOWARE + "PredictedObjects": """
std_msgs/Header header
autoware_perception_msgs/PredictedObject[] objects
""",
    PLANNING + "TrajectoryPoint": """
builtin_interfaces/Duration time_from_start
geometry_msgs/Pose pose
float32 longitudinal_velocity_mps
float32 lateral_velocity_mps
float32 acceleration_mps2
float32 heading_rate_rps
float32 front_wheel_angle_rad
float32 rear_wheel_angle_rad
""",
    PLANNING + "Trajectory": """
std_msgs/Header header
autoware_planning_msgs/TrajectoryPoint[] points
""",
}
"""Autoware's own types (autoware_msgs 1.12.0), which rosbags' Jazzy typestore lacks, as `.msg` text per
type name: fields and the constants this package writes, the upstream files' comments left out.
With ROS 2 sourced, test_interfaces holds every type's bytes and RIHS01 hash to the upstream packages'."""
register_types(MESSAGE_TYPES)
T = TYPESTORE.types
DETECTED = "autoware_perception_msgs/msg/DetectedObjects"
TRACKED = "autoware_perception_msgs/msg/TrackedObjects"
PREDICTED = "autoware_perception_msgs/msg/PredictedObjects"
TRAJECTORY = "autoware_planning_msgs/msg/Trajectory"

DETECTIONS_TOPIC = "/perception/object_recognition/detection/objects"
OBJECTS_TOPIC = "/perception/object_recognition/objects"
TRACKED_TOPIC = "/perception/object_recognition/tracking/objects"
TRAJECTORY_TOPIC = "/planning/scenario_planning/trajectory"
KINEMATIC_STATE_TOPIC = "/localization/kinematic_state"
ACCELERATION_TOPIC = "/localization/acceleration"  # geometry_msgs/AccelWithCovarianceStamped, in base_link
TRANSFORMS_TOPIC = "/tf"  # tf2_msgs/TFMessage: map -> base_link, which Autoware's nodes look up through tf2

PREDICTION_HORIZON = 8.0  # s
PREDICTION_STEP = 0.5  # s
STOPPED_SPEED = 1e-3  # m/s: a trajectory timed from its speeds ends where they fall below this
STOP_HOLD = 3600.0  # s: a trajectory that stops there holds its stop point this long
MERGE_DISTANCE = 1e-3  # m: points this close are one (a foot on a sample would make a step of no time)
_CAR = 1  # ObjectClassification.CAR
_BOUNDING_BOX, _CYLINDER, _POLYGON = 0, 1, 2  # Shape.type
_AVAILABLE = 2  # orientation_availability
_ZEROS_36 = np.zeros(36)


def _uuid(object_id: int):
    return T["unique_identifier_msgs/msg/UUID"](
        uuid=np.frombuffer(int(object_id).to_bytes(8, "little", signed=True) + bytes(8), np.uint8).copy())


def _vector3(x: float = 0.0, y: float = 0.0, z: float = 0.0):
    return T["geometry_msgs/msg/Vector3"](x=float(x), y=float(y), z=float(z))


def _with_covariance(kind: str, value):
    field = "pose" if kind == "Pose" else "twist" if kind == "Twist" else "accel"
    return T[f"geometry_msgs/msg/{kind}WithCovariance"](**{field: value, "covariance": _ZEROS_36.copy()})


def _twist(vx: float, vy: float, yaw: float):
    """The object-frame twist of a `map`-frame velocity."""
    cos, sin = math.cos(yaw), math.sin(yaw)
    return T["geometry_msgs/msg/Twist"](linear=_vector3(cos * vx + sin * vy, -sin * vx + cos * vy), angular=_vector3())


def _shape(length: float, width: float, height: float):
    return T["autoware_perception_msgs/msg/Shape"](type=_BOUNDING_BOX, footprint=T["geometry_msgs/msg/Polygon"](points=[]),
                                                   dimensions=_vector3(length, width, height))


def _classification():
    return [T["autoware_perception_msgs/msg/ObjectClassification"](label=_CAR, probability=1.0)]


def _rows(objects: Objects):
    return zip(objects["ids"].tolist(), *(objects[name].tolist() for name in BOX_FIELDS))


def _duration(ns: int):
    return T["builtin_interfaces/msg/Duration"](sec=int(ns // 1_000_000_000), nanosec=int(ns % 1_000_000_000))


def _predicted_path(x: float, y: float, yaw: float, vx: float, vy: float):
    steps = np.arange(int(round(PREDICTION_HORIZON / PREDICTION_STEP)) + 1) * PREDICTION_STEP
    return T["autoware_perception_msgs/msg/PredictedPath"](
        path=[msgs.pose(x + vx * s, y + vy * s, yaw) for s in steps.tolist()],
        time_step=_duration(int(round(PREDICTION_STEP * 1e9))), confidence=1.0)


def _objects_message(msgtype: str, objects: Objects, stamp_ns: int, build: Callable[..., Any]) -> bytes:
    """The CDR of an Autoware objects array of `msgtype`: one `build(id, *BOX_FIELDS)` per box."""
    msg = T[msgtype](header=msgs.header(stamp_ns), objects=[build(*row) for row in _rows(objects)])
    return bytes(TYPESTORE.serialize_cdr(msg, msgtype))


def _motion(x: float, y: float, yaw: float, vx: float, vy: float) -> tuple[Any, Any, Any]:
    """(pose, twist, acceleration) with covariance, as every Autoware kinematics type holds them."""
    still = T["geometry_msgs/msg/Accel"](linear=_vector3(), angular=_vector3())
    return (_with_covariance("Pose", msgs.pose(x, y, yaw)), _with_covariance("Twist", _twist(vx, vy, yaw)),
            _with_covariance("Accel", still))


def _detected(object_id: int, x: float, y: float, yaw: float, vx: float, vy: float, length: float, width: float,
              height: float, score: float) -> Any:
    pose, twist, _ = _motion(x, y, yaw, vx, vy)
    kinematics = T["autoware_perception_msgs/msg/DetectedObjectKinematics"](
        pose_with_covariance=pose, has_position_covariance=False, orientation_availability=_AVAILABLE,
        twist_with_covariance=twist, has_twist=True, has_twist_covariance=False)
    return T["autoware_perception_msgs/msg/DetectedObject"](
        existence_probability=_probability(score), classification=_classification(), kinematics=kinematics,
        shape=_shape(length, width, height))


def _tracked(object_id: int, x: float, y: float, yaw: float, vx: float, vy: float, length: float, width: float,
             height: float, score: float) -> Any:
    pose, twist, accel = _motion(x, y, yaw, vx, vy)
    kinematics = T["autoware_perception_msgs/msg/TrackedObjectKinematics"](
        pose_with_covariance=pose, twist_with_covariance=twist, acceleration_with_covariance=accel,
        orientation_availability=_AVAILABLE, is_stationary=False)
    return T["autoware_perception_msgs/msg/TrackedObject"](
        object_id=_uuid(object_id), existence_probability=_probability(score), classification=_classification(),
        kinematics=kinematics, shape=_shape(length, width, height))


def _predicted(object_id: int, x: float, y: float, yaw: float, vx: float, vy: float, length: float, width: float,
               height: float, score: float) -> Any:
    pose, twist, accel = _motion(x, y, yaw, vx, vy)
    kinematics = T["autoware_perception_msgs/msg/PredictedObjectKinematics"](
        initial_pose_with_covariance=pose, initial_twist_with_covariance=twist,
        initial_acceleration_with_covariance=accel, predicted_paths=[_predicted_path(x, y, yaw, vx, vy)])
    return T["autoware_perception_msgs/msg/PredictedObject"](
        object_id=_uuid(object_id), existence_probability=_probability(score), classification=_classification(),
        kinematics=kinematics, shape=_shape(length, width, height))


def encode_detected(objects: Objects, stamp_ns: int, kind: str = "perception") -> bytes:
    """A frame of boxes as a DetectedObjects' CDR (`kind` unused: the type has no colour)."""
    return _objects_message(DETECTED, objects, stamp_ns, _detected)


def encode_tracked(objects: Objects, stamp_ns: int, kind: str = "tracking") -> bytes:
    """A frame of boxes as a TrackedObjects' CDR."""
    return _objects_message(TRACKED, objects, stamp_ns, _tracked)


def encode_predicted(objects: Objects, stamp_ns: int, kind: str = "tracking") -> bytes:
    """A frame of boxes as a PredictedObjects' CDR, each with its constant-velocity path."""
    return _objects_message(PREDICTED, objects, stamp_ns, _predicted)


def _probability(score: float) -> float:
    """A detection confidence as `existence_probability`; ground truth and tracks (nan) as 1."""
    return 1.0 if math.isnan(score) else float(score)


def _dimensions(shape, where: str) -> tuple[float, float, float]:
    size = shape.dimensions
    if shape.type == _BOUNDING_BOX:
        return size.x, size.y, size.z
    if shape.type == _CYLINDER:
        return size.x, size.x, size.z
    if shape.type == _POLYGON:
        points = np.array([[p.x, p.y] for p in shape.footprint.points], dtype=float).reshape(-1, 2)
        if not len(points):
            raise MessageError(f"{where}: field 'shape.footprint' of a POLYGON shape has no points")
        extent = points.max(axis=0) - points.min(axis=0)
        return float(extent[0]), float(extent[1]), size.z
    raise MessageError(f"{where}: field 'shape.type' is {shape.type}, not BOUNDING_BOX, CYLINDER or POLYGON")


def _box(pose, twist, shape, score: float, where: str) -> tuple[float, ...]:
    q = pose.orientation
    yaw = quaternion_yaw(q.x, q.y, q.z, q.w)
    cos, sin = math.cos(yaw), math.sin(yaw)
    tx, ty = twist.linear.x, twist.linear.y
    return (pose.position.x, pose.position.y, yaw, cos * tx - sin * ty, sin * tx + cos * ty,
            *_dimensions(shape, where), float(score))


HASHED_IDS = 1 << 30  # a UUID not of our layout reads back as an id in [HASHED_IDS, 2 * HASHED_IDS)


def uuid_id(uuid: bytes) -> int:
    """The id a 16-byte UUID reads back as: ours (an int32 in the first 8 bytes, the rest zero) as itself,
    so an id read back and sent out again stays itself; any other as 30 bits of its BLAKE2b digest above
    HASHED_IDS (stable across runs and machines)."""
    ours = int.from_bytes(uuid[:8], "little", signed=True)
    if not any(uuid[8:]) and -2 * HASHED_IDS <= ours < 2 * HASHED_IDS:  # an int32: ours, or read back before
        return ours
    digest = int.from_bytes(hashlib.blake2b(uuid, digest_size=8).digest(), "little")
    return HASHED_IDS | (digest & (HASHED_IDS - 1))


def _uuid_bytes(uuid) -> bytes:
    return bytes(np.asarray(uuid.uuid, dtype=np.uint8))


def _object_id(uuid) -> int:
    return uuid_id(_uuid_bytes(uuid))


def _uuids_of(msgtype: str) -> Callable[[Cdr, str], dict[int, str]]:
    def uuids(data: Cdr, where: str) -> dict[int, str]:
        """Each object's id (as `decode` gives it) -> its UUID as 32 hex digits."""
        return {_object_id(item.object_id): _uuid_bytes(item.object_id).hex()
                for item in deserialize(data, msgtype, where).objects}
    return uuids


def decode_detected(data: Cdr, where: str) -> tuple[int | None, Objects]:
    msg = deserialize(data, DETECTED, where)
    rows = []
    for i, item in enumerate(msg.objects):
        k = item.kinematics
        twist = k.twist_with_covariance.twist if k.has_twist else T["geometry_msgs/msg/Twist"](
            linear=_vector3(), angular=_vector3())
        rows.append(_box(k.pose_with_covariance.pose, twist, item.shape, item.existence_probability, f"{where}, object {i}"))
    return msgs.stamp_ns(msg.header.stamp), objects_from_rows(list(range(len(rows))), rows, where)


def decode_tracked(data: Cdr, where: str) -> tuple[int | None, Objects]:
    msg = deserialize(data, TRACKED, where)
    rows = [_box(item.kinematics.pose_with_covariance.pose, item.kinematics.twist_with_covariance.twist, item.shape,
                 item.existence_probability, f"{where}, object {i}") for i, item in enumerate(msg.objects)]
    ids = [_object_id(item.object_id) for item in msg.objects]
    return msgs.stamp_ns(msg.header.stamp), objects_from_rows(ids, rows, where)


def decode_predicted(data: Cdr, where: str) -> tuple[int | None, Objects]:
    msg = deserialize(data, PREDICTED, where)
    rows = [_box(item.kinematics.initial_pose_with_covariance.pose, item.kinematics.initial_twist_with_covariance.twist,
                 item.shape, item.existence_probability, f"{where}, object {i}") for i, item in enumerate(msg.objects)]
    ids = [_object_id(item.object_id) for item in msg.objects]
    return msgs.stamp_ns(msg.header.stamp), objects_from_rows(ids, rows, where)


def encode_trajectory(plan: Trajectory, stamp_ns: int) -> bytes:
    """A plan computed at `stamp_ns` as a Trajectory's CDR: each point's `time_from_start` is its
    time since the plan's first, in whole nanoseconds as `messages.trajectory_cdr` stamps a Path's
    poses; `longitudinal_velocity_mps` is the speed along the poses towards the next point."""
    offsets = np.rint(np.asarray(plan.t) * 1e9).astype(np.int64)
    xs, ys = np.asarray(plan.x, dtype=float), np.asarray(plan.y, dtype=float)
    steps = np.hypot(np.diff(xs), np.diff(ys)) / np.maximum(np.diff(offsets) * 1e-9, 1e-9)
    speeds = np.append(steps, steps[-1:]) if len(steps) else np.zeros(len(xs))
    points = [T["autoware_planning_msgs/msg/TrajectoryPoint"](
        time_from_start=_duration(int(offset - offsets[0])), pose=msgs.pose(x, y, yaw), longitudinal_velocity_mps=float(v),
        lateral_velocity_mps=0.0, acceleration_mps2=0.0, heading_rate_rps=0.0, front_wheel_angle_rad=0.0,
        rear_wheel_angle_rad=0.0)
        for offset, x, y, yaw, v in zip(offsets.tolist(), xs.tolist(), ys.tolist(), np.asarray(plan.yaw).tolist(),
                                        speeds.tolist())]
    msg = T[TRAJECTORY](header=msgs.header(stamp_ns), points=points)
    return bytes(TYPESTORE.serialize_cdr(msg, TRAJECTORY))


def decode_trajectory(data: Cdr, first_stamp_ns: int, ego_xy: tuple[float, float], where: str) -> tuple[int, Trajectory]:
    """A Trajectory's CDR as (its stamp, the plan timed as the module docstring says)."""
    msg = deserialize(data, TRAJECTORY, where)
    stamp = msgs.stamp_ns(msg.header.stamp)
    points = msg.points
    xs = np.array([p.pose.position.x for p in points], dtype=float)
    ys = np.array([p.pose.position.y for p in points], dtype=float)
    yaws = np.array([quaternion_yaw(p.pose.orientation.x, p.pose.orientation.y, p.pose.orientation.z,
                                    p.pose.orientation.w) for p in points], dtype=float)
    offsets = np.array([p.time_from_start.sec * 1_000_000_000 + p.time_from_start.nanosec for p in points], dtype=np.int64)
    if len(points) > 1 and np.any(offsets != offsets[0]):
        t = (np.int64(stamp) + offsets - offsets[0] - np.int64(first_stamp_ns)) * 1e-9
        return stamp, Trajectory(t=t, x=xs, y=ys, yaw=yaws)
    speeds = np.array([p.longitudinal_velocity_mps for p in points], dtype=float)
    return stamp, _timed_by_speed(xs, ys, yaws, speeds, (stamp - first_stamp_ns) * 1e-9, ego_xy)


def _timed_by_speed(xs: np.ndarray, ys: np.ndarray, yaws: np.ndarray, speeds: np.ndarray, now: float,
                    ego_xy: tuple[float, float]) -> Trajectory:
    if len(xs) < 2:
        return Trajectory(t=np.zeros(0), x=xs[:0], y=ys[:0], yaw=yaws[:0])
    # the ego's foot on the polyline (the nearest point of the nearest segment), where the plan's time is now
    dx, dy = np.diff(xs), np.diff(ys)
    lengths2 = np.maximum(dx * dx + dy * dy, 1e-18)
    u = np.clip(((ego_xy[0] - xs[:-1]) * dx + (ego_xy[1] - ys[:-1]) * dy) / lengths2, 0.0, 1.0)
    segment = int(np.argmin(np.hypot(xs[:-1] + u * dx - ego_xy[0], ys[:-1] + u * dy - ego_xy[1])))
    w = float(u[segment])
    foot = (xs[segment] + w * dx[segment], ys[segment] + w * dy[segment],
            yaws[segment] + w * _angle(yaws[segment + 1] - yaws[segment]),
            speeds[segment] + w * (speeds[segment + 1] - speeds[segment]))
    rest = slice(segment + 1, None)
    xs, ys = np.append(foot[0], xs[rest]), np.append(foot[1], ys[rest])
    yaws, speeds = np.append(foot[2], yaws[rest]), np.append(foot[3], speeds[rest])
    keep = np.append(True, np.hypot(np.diff(xs), np.diff(ys)) > MERGE_DISTANCE)  # the foot on a point: that point once
    xs, ys, yaws, speeds = xs[keep], ys[keep], yaws[keep], speeds[keep]
    mean = (speeds[:-1] + speeds[1:]) / 2
    stopped = np.flatnonzero(mean < STOPPED_SPEED)
    end = int(stopped[0]) + 1 if len(stopped) else len(xs)  # the last point reached before a stop
    t = now + np.concatenate(([0.0], np.cumsum(np.hypot(np.diff(xs[:end]), np.diff(ys[:end])) / mean[:end - 1])))
    xs, ys, yaws = xs[:end], ys[:end], yaws[:end]
    if len(stopped):  # it stops there and waits: the stop point held for STOP_HOLD
        t, xs, ys, yaws = (np.append(t, t[-1] + STOP_HOLD), np.append(xs, xs[-1]), np.append(ys, ys[-1]),
                           np.append(yaws, yaws[-1]))
    return Trajectory(t=t, x=xs, y=ys, yaw=yaws)


def _angle(delta: float) -> float:
    """`delta` wrapped to [-pi, pi): the short way between two headings."""
    return (delta + math.pi) % (2 * math.pi) - math.pi


PROFILE = Profile(
    name="autoware",
    description="Autoware's types and topic names: DetectedObjects in, PredictedObjects to the planner, "
                "Trajectory back, Odometry on /localization/kinematic_state",
    detections=ObjectsLayer(DETECTIONS_TOPIC, DETECTED, encode_detected, decode_detected, import_rank=3),
    tracks=ObjectsLayer(OBJECTS_TOPIC, PREDICTED, encode_predicted, decode_predicted, import_rank=0,
                        uuids=_uuids_of(PREDICTED)),
    plan=PlanLayer(TRAJECTORY_TOPIC, TRAJECTORY, encode_trajectory, decode_trajectory),
    ego_topic=KINEMATIC_STATE_TOPIC,
    acceleration_topic=ACCELERATION_TOPIC,
    transforms_topic=TRANSFORMS_TOPIC,
    message_types=MESSAGE_TYPES,
)

TRACKED_PROFILE = Profile(
    name="autoware_tracked",
    description="as autoware, but the tracked objects go out as TrackedObjects on "
                "/perception/object_recognition/tracking/objects, for a team that brings its own prediction node",
    detections=PROFILE.detections,
    tracks=ObjectsLayer(TRACKED_TOPIC, TRACKED, encode_tracked, decode_tracked, import_rank=1,
                        uuids=_uuids_of(TRACKED)),
    plan=PROFILE.plan,
    ego_topic=KINEMATIC_STATE_TOPIC,
    acceleration_topic=ACCELERATION_TOPIC,
    transforms_topic=TRANSFORMS_TOPIC,
    message_types=MESSAGE_TYPES,
)
