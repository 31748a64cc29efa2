"""ROS 2 Jazzy messages of the topic contract, built from the rosbags typestore (no rclpy needed).

Object convention (one MarkerArray per frame, frame `map`): the first marker is DELETEALL; then per
object a CUBE in namespace `objects` (id = agent or track id, pose = centre and yaw, scale =
length, width, height, text = detection confidence as a decimal string, empty for ground truth and
tracks) and an ARROW with the same id in namespace `velocity` whose points are [centre,
centre + velocity x 1 s]. A dropped object is simply absent.

rosbags message classes have no defaults and want numpy arrays for primitive arrays; the small
factories below fill every field.
"""

import numpy as np
from rosbags.typesys import Stores, get_typestore

from advperc_ros.core.planners.base import Trajectory
from advperc_ros.core.scenario import EgoState, Lane

TYPESTORE = get_typestore(Stores.ROS2_JAZZY)
T = TYPESTORE.types
FRAME_ID = "map"
OBJECTS_NS = "objects"
VELOCITY_NS = "velocity"
LANES_NS = "lanes"
OBJECT_HEIGHT_DEFAULT = 1.6

COLORS = {
    "ground_truth": (1.0, 1.0, 1.0, 0.8),
    "perception": (0.1, 0.8, 0.2, 0.8),
    "tracking": (0.2, 0.4, 1.0, 0.8),
    "lanes": (0.3, 0.3, 0.3, 0.5),
}


class MessageError(ValueError):
    """A message that does not follow the topic contract; the text names the field."""


def stamp(ns: int):
    return T["builtin_interfaces/msg/Time"](sec=int(ns // 1_000_000_000), nanosec=int(ns % 1_000_000_000))


def stamp_ns(time) -> int:
    return int(time.sec) * 1_000_000_000 + int(time.nanosec)


def header(ns: int, frame_id: str = FRAME_ID):
    return T["std_msgs/msg/Header"](stamp=stamp(ns), frame_id=frame_id)


def _point(x: float, y: float, z: float = 0.0):
    return T["geometry_msgs/msg/Point"](x=float(x), y=float(y), z=float(z))


def _quaternion(yaw: float):
    return T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=float(np.sin(yaw / 2.0)), w=float(np.cos(yaw / 2.0)))


def _yaw(q) -> float:
    return float(np.arctan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z)))


def _pose(x: float, y: float, yaw: float, z: float = 0.0):
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
    Marker = T["visualization_msgs/msg/Marker"]
    identity = _pose(0.0, 0.0, 0.0)
    markers = [_marker(ns_time, "", 0, Marker.CUBE, Marker.DELETEALL, identity, (0, 0, 0), _color(kind), [])]
    color = _color(kind)
    for i in range(len(objects["ids"])):
        x, y = objects["x"][i], objects["y"][i]
        height = objects["height"][i]
        confidence = objects["score"][i]
        text = repr(float(confidence)) if np.isfinite(confidence) else ""
        size = (objects["length"][i], objects["width"][i], height)
        pose = _pose(x, y, objects["yaw"][i], height / 2.0)
        markers.append(_marker(ns_time, OBJECTS_NS, objects["ids"][i], Marker.CUBE, Marker.ADD, pose, size, color, [], text))
        tip = [_point(x, y, height / 2.0), _point(x + objects["vx"][i], y + objects["vy"][i], height / 2.0)]
        markers.append(
            _marker(ns_time, VELOCITY_NS, objects["ids"][i], Marker.ARROW, Marker.ADD, identity, (0.2, 0.4, 0.4), color, tip)
        )
    return T["visualization_msgs/msg/MarkerArray"](markers=markers)


def markers_to_objects(msg, where: str) -> dict[str, np.ndarray]:
    """Decode the object convention; `where` (file and topic) prefixes any error."""
    cubes: dict[int, object] = {}
    arrows: dict[int, object] = {}
    for marker in msg.markers:
        if marker.action == 3:  # DELETEALL
            continue
        if marker.ns == OBJECTS_NS:
            cubes[int(marker.id)] = marker
        elif marker.ns == VELOCITY_NS:
            arrows[int(marker.id)] = marker
    ids = sorted(cubes)
    out: dict[str, list[float]] = {name: [] for name in ("x", "y", "yaw", "vx", "vy", "length", "width", "height", "score")}
    for marker_id in ids:
        cube = cubes[marker_id]
        out["x"].append(cube.pose.position.x)
        out["y"].append(cube.pose.position.y)
        out["yaw"].append(_yaw(cube.pose.orientation))
        out["length"].append(cube.scale.x)
        out["width"].append(cube.scale.y)
        out["height"].append(cube.scale.z)
        try:
            out["score"].append(float(cube.text) if cube.text else np.nan)
        except ValueError:
            raise MessageError(f"{where}: field 'text' of marker {marker_id} is not a confidence: {cube.text!r}") from None
        arrow = arrows.get(marker_id)
        if arrow is not None and len(arrow.points) == 2:
            out["vx"].append(arrow.points[1].x - arrow.points[0].x)
            out["vy"].append(arrow.points[1].y - arrow.points[0].y)
        else:
            out["vx"].append(0.0)
            out["vy"].append(0.0)
    result = {name: np.asarray(values, dtype=float) for name, values in out.items()}
    result["ids"] = np.asarray(ids, dtype=np.int64)
    return result


def odometry(ego: EgoState, ns_time: int):
    cov = np.zeros(36)
    twist = T["geometry_msgs/msg/Twist"](
        linear=T["geometry_msgs/msg/Vector3"](x=float(ego.v), y=0.0, z=0.0),
        angular=T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0),
    )
    return T["nav_msgs/msg/Odometry"](
        header=header(ns_time),
        child_frame_id="base_link",
        pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=_pose(ego.x, ego.y, ego.yaw), covariance=cov),
        twist=T["geometry_msgs/msg/TwistWithCovariance"](twist=twist, covariance=cov.copy()),
    )


def odometry_to_ego(msg) -> EgoState:
    pose = msg.pose.pose
    return EgoState(x=pose.position.x, y=pose.position.y, yaw=_yaw(pose.orientation), v=msg.twist.twist.linear.x)


def path(xs: np.ndarray, ys: np.ndarray, yaws: np.ndarray, stamps: list[int], ns_time: int):
    poses = [
        T["geometry_msgs/msg/PoseStamped"](header=header(s), pose=_pose(x, y, yaw))
        for x, y, yaw, s in zip(xs, ys, yaws, stamps)
    ]
    return T["nav_msgs/msg/Path"](header=header(ns_time), poses=poses)


def trajectory_to_path(plan: Trajectory, ns_time: int):
    """A plan as nav_msgs/Path; each pose is stamped with its absolute simulation time."""
    origin = ns_time - int(round(plan.t[0] * 1e9))
    stamps = [origin + int(round(t * 1e9)) for t in plan.t]
    return path(plan.x, plan.y, plan.yaw, stamps, ns_time)


def lanes_to_markers(lanes: tuple[Lane, ...], ns_time: int):
    """Lanes as LINE_STRIP markers along the centreline, scale.x = lane width."""
    Marker = T["visualization_msgs/msg/Marker"]
    markers = []
    for i, lane in enumerate(lanes):
        points = [_point(x, y) for x, y in lane.centerline.points]
        marker = _marker(
            ns_time, LANES_NS, i, Marker.LINE_STRIP, Marker.ADD, _pose(0, 0, 0), (lane.width, 0, 0), _color("lanes"), points, lane.id
        )
        markers.append(marker)
    return T["visualization_msgs/msg/MarkerArray"](markers=markers)


def markers_to_lanes(msg) -> list[tuple[str, np.ndarray, float]]:
    return [
        (m.text, np.array([[p.x, p.y] for p in m.points]), float(m.scale.x))
        for m in msg.markers
        if m.ns == LANES_NS and len(m.points) >= 2
    ]


def path_points(msg) -> tuple[np.ndarray, np.ndarray]:
    """(poses (P, 3) as x, y, yaw; stamps (P,) ns) of a nav_msgs/Path."""
    poses = np.array([[p.pose.position.x, p.pose.position.y, _yaw(p.pose.orientation)] for p in msg.poses]).reshape(-1, 3)
    stamps = np.array([stamp_ns(p.header.stamp) for p in msg.poses], dtype=np.int64)
    return poses, stamps


def clock(ns_time: int):
    return T["rosgraph_msgs/msg/Clock"](clock=stamp(ns_time))


def float64(value: float):
    return T["std_msgs/msg/Float64"](data=float(value))


def string(text: str):
    return T["std_msgs/msg/String"](data=text)


def diagnostics(ns_time: int, name: str, message: str, values: dict[str, str], level: int = 0):
    status = T["diagnostic_msgs/msg/DiagnosticStatus"](
        level=level,
        name=name,
        message=message,
        hardware_id="advperc",
        values=[T["diagnostic_msgs/msg/KeyValue"](key=k, value=v) for k, v in values.items()],
    )
    return T["diagnostic_msgs/msg/DiagnosticArray"](header=header(ns_time), status=[status])
