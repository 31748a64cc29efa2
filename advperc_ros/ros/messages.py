"""ROS 2 Jazzy messages of the topic contract as rosbags objects (no rclpy needed).

For bags, tools and tests. The object MarkerArrays, Paths, Odometry, Clock, Float64 and
DiagnosticArrays are made from, and read through, the CDR codecs of `advperc_ros.ros.cdr`, which also define the
object convention; the graph nodes use those codecs directly, without rosbags objects. rosbags
message classes have no defaults and want numpy arrays for primitive arrays; the small factories
below fill every field.
"""

from typing import Any

import numpy as np

from advperc_ros.core.planners.base import Trajectory
from advperc_ros.core.scenario import EgoState, Lane
from advperc_ros.ros import cdr
from advperc_ros.ros.cdr import COLORS, DIAGNOSTICS, FRAME_ID, MARKER_ARRAY, ODOMETRY, PATH, TYPESTORE

T = TYPESTORE.types
LANES_NS = "lanes"
HARDWARE_ID = "advperc"


def stamp(ns: int):
    return T["builtin_interfaces/msg/Time"](sec=int(ns // 1_000_000_000), nanosec=int(ns % 1_000_000_000))


def stamp_ns(time) -> int:
    return int(time.sec) * 1_000_000_000 + int(time.nanosec)


def header(ns: int, frame_id: str = FRAME_ID):
    return T["std_msgs/msg/Header"](stamp=stamp(ns), frame_id=frame_id)


def _point(x: float, y: float, z: float = 0.0):
    return T["geometry_msgs/msg/Point"](x=float(x), y=float(y), z=float(z))


def _quaternion(yaw: float):
    z, w = cdr.yaw_quaternion(yaw)
    return T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=float(z), w=float(w))


def pose(x: float, y: float, yaw: float, z: float = 0.0):
    """A geometry_msgs/Pose at (x, y, z) heading `yaw`."""
    return T["geometry_msgs/msg/Pose"](position=_point(x, y, z), orientation=_quaternion(yaw))


def _color(kind: str):
    r, g, b, a = COLORS[kind]
    return T["std_msgs/msg/ColorRGBA"](r=r, g=g, b=b, a=a)


def _marker(ns_time: int, ns: str, marker_id: int, marker_type: int, action: int, pose, scale, color, points, text=""):
    return T["visualization_msgs/msg/Marker"](
        header=header(ns_time),
        ns=ns,
        id=int(marker_id),
        type=marker_type,
        action=action,
        pose=pose,
        scale=T["geometry_msgs/msg/Vector3"](x=float(scale[0]), y=float(scale[1]), z=float(scale[2])),
        color=color,
        lifetime=T["builtin_interfaces/msg/Duration"](sec=0, nanosec=0),
        frame_locked=False,
        points=points,
        colors=[],
        texture_resource="",
        texture=T["sensor_msgs/msg/CompressedImage"](header=header(0, ""), format="", data=np.zeros(0, np.uint8)),
        uv_coordinates=[],
        text=text,
        mesh_resource="",
        mesh_file=T["visualization_msgs/msg/MeshFile"](filename="", data=np.zeros(0, np.uint8)),
        mesh_use_embedded_materials=False,
    )


def objects_to_markers(objects: dict[str, np.ndarray], ns_time: int, kind: str):
    """A frame of boxes (dict of 1-D arrays: ids and BOX_FIELDS) as a MarkerArray."""
    return TYPESTORE.deserialize_cdr(cdr.encode_objects(objects, ns_time, kind), MARKER_ARRAY)


def ego_to_cdr(ego: EgoState, ns_time: int) -> bytes:
    """The ego state as the CDR of a nav_msgs/Odometry stamped `ns_time` (speed in twist.linear.x)."""
    return cdr.encode_odometry(ego.x, ego.y, ego.yaw, ego.v, ns_time)


def ego_from_cdr(data: cdr.Cdr, where: str) -> tuple[int, EgoState]:
    """(stamp, ego state) of a nav_msgs/Odometry's CDR; `where` prefixes any error."""
    stamp, state = cdr.decode_odometry(data, where)
    return stamp, EgoState(*state)


def footprint_cdr(length: float, width: float, ns_time: int) -> bytes:
    """The ego's box as a geometry_msgs/PolygonStamped's CDR, in the odometry's child frame: its
    corners around the reference point (the odometry's pose, the box's centre), counter-clockwise
    from the front left; a planner reads the ego's size here instead of being told it."""
    corners = [(length / 2, width / 2), (-length / 2, width / 2), (-length / 2, -width / 2), (length / 2, -width / 2)]
    polygon = T["geometry_msgs/msg/Polygon"](points=[T["geometry_msgs/msg/Point32"](x=x, y=y, z=0.0) for x, y in corners])
    message = T["geometry_msgs/msg/PolygonStamped"](header=header(ns_time, cdr.CHILD_FRAME_ID), polygon=polygon)
    return cdr.payload(message, "geometry_msgs/msg/PolygonStamped")


ACCELERATION = "geometry_msgs/msg/AccelWithCovarianceStamped"


def acceleration_cdr(longitudinal: float, ns_time: int) -> bytes:
    """The ego's acceleration along its heading (m/s^2) as a geometry_msgs/AccelWithCovarianceStamped's
    CDR in the odometry's child frame, as Autoware's localization publishes it; covariance zero."""
    vector = T["geometry_msgs/msg/Vector3"]
    accel = T["geometry_msgs/msg/Accel"](linear=vector(x=float(longitudinal), y=0.0, z=0.0),
                                         angular=vector(x=0.0, y=0.0, z=0.0))
    message = T[ACCELERATION](header=header(ns_time, cdr.CHILD_FRAME_ID), accel=T["geometry_msgs/msg/AccelWithCovariance"](
        accel=accel, covariance=np.zeros(36)))
    return cdr.payload(message, ACCELERATION)


TRANSFORMS = "tf2_msgs/msg/TFMessage"


def transform_cdr(ego: EgoState, ns_time: int) -> bytes:
    """The ego's pose as the one transform map -> base_link (FRAME_ID -> CHILD_FRAME_ID) of a
    tf2_msgs/TFMessage's CDR stamped `ns_time`: where the odometry puts it, the centre of its box."""
    transform = T["geometry_msgs/msg/Transform"](
        translation=T["geometry_msgs/msg/Vector3"](x=float(ego.x), y=float(ego.y), z=0.0), rotation=_quaternion(ego.yaw))
    stamped = T["geometry_msgs/msg/TransformStamped"](header=header(ns_time), child_frame_id=cdr.CHILD_FRAME_ID,
                                                      transform=transform)
    return cdr.payload(T[TRANSFORMS](transforms=[stamped]), TRANSFORMS)


def odometry(ego: EgoState, ns_time: int):
    return TYPESTORE.deserialize_cdr(ego_to_cdr(ego, ns_time), ODOMETRY)


def odometry_to_ego(msg) -> EgoState:
    return ego_from_cdr(TYPESTORE.serialize_cdr(msg, ODOMETRY), ODOMETRY)[1]


def trajectory_cdr(plan: Trajectory, ns_time: int) -> bytes:
    """A plan computed at `ns_time` as the CDR of a nav_msgs/Path stamped `ns_time`; each pose is
    stamped with its absolute simulation time (plan times rounded to whole nanoseconds)."""
    offsets = np.rint(np.asarray(plan.t) * 1e9).astype(np.int64)
    return cdr.encode_path(plan.x, plan.y, plan.yaw, ns_time - offsets[:1] + offsets, ns_time)


def trajectory_to_path(plan: Trajectory, ns_time: int):
    """`trajectory_cdr` as a rosbags nav_msgs/Path."""
    return TYPESTORE.deserialize_cdr(trajectory_cdr(plan, ns_time), PATH)


def lanes_to_markers(lanes: tuple[Lane, ...], ns_time: int):
    """Lanes as LINE_STRIP markers along the centreline, scale.x = lane width."""
    Marker: Any = T["visualization_msgs/msg/Marker"]  # built at run time: its constants are not typed
    markers = []
    for i, lane in enumerate(lanes):
        points = [_point(x, y) for x, y in lane.centerline.points]
        marker = _marker(
            ns_time, LANES_NS, i, Marker.LINE_STRIP, Marker.ADD, pose(0, 0, 0), (lane.width, 0, 0), _color("lanes"), points,
            lane.id,
        )
        markers.append(marker)
    return T["visualization_msgs/msg/MarkerArray"](markers=markers)


def markers_to_lanes(msg) -> list[tuple[str, np.ndarray, float]]:
    """(id, centreline points (P, 2), width) of every marker in namespace `lanes`, however few
    its points: the caller refuses a lane it cannot use rather than losing it here."""
    return [
        (m.text, np.array([[p.x, p.y] for p in m.points]).reshape(-1, 2), float(m.scale.x))
        for m in msg.markers
        if m.ns == LANES_NS
    ]


def path_points(msg) -> tuple[np.ndarray, np.ndarray]:
    """(poses (P, 3) as x, y, yaw; stamps (P,) ns) of a nav_msgs/Path."""
    _, poses, stamps = cdr.decode_path(TYPESTORE.serialize_cdr(msg, PATH), PATH)
    return poses, stamps


def clock(ns_time: int):
    return TYPESTORE.deserialize_cdr(cdr.encode_clock(ns_time), "rosgraph_msgs/msg/Clock")


def float64(value: float):
    return TYPESTORE.deserialize_cdr(cdr.encode_float64(value), "std_msgs/msg/Float64")


def string(text: str):
    return T["std_msgs/msg/String"](data=text)


def diagnostics_cdr(ns_time: int, name: str, message: str, values: dict[str, str], level: int = 0) -> bytes:
    """A DiagnosticArray's CDR with one status of ours (hardware_id `advperc`)."""
    return cdr.encode_diagnostics(ns_time, cdr.Status(level, name, message, HARDWARE_ID, values))


def diagnostics(ns_time: int, name: str, message: str, values: dict[str, str], level: int = 0):
    return TYPESTORE.deserialize_cdr(diagnostics_cdr(ns_time, name, message, values, level), DIAGNOSTICS)
