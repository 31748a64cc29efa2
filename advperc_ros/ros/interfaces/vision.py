"""`vision_msgs`: a detector publishing `vision_msgs/Detection3DArray` (as many 3-D detectors in
ROS 2 do) feeds the graph's tracker; tracks, plan and ego stay in the graph's own types.

Conversions: a box is `bbox` (centre pose and size: length, width, height); its confidence the
best `results[].hypothesis.score` (float64, exact; none: nan) and its class `car`; its id the
decimal `id` string (a detector's boxes without one read back numbered 0..n-1). The type has no
velocity: detections read back standing still, so our tracker starts each track at rest and
learns its speed from the following frames, where the paper's detections hand it their
velocity. Attacks through this profile are therefore their own, not the MarkerArray profile's.
"""

import math

import numpy as np

from advperc_ros.ros import messages as msgs
from advperc_ros.ros.cdr import TYPESTORE, Cdr, deserialize, quaternion_yaw, register_types
from advperc_ros.ros.interfaces import advperc
from advperc_ros.ros.interfaces.base import Objects, ObjectsLayer, Profile, objects_from_rows

VISION = "vision_msgs/msg/"
MESSAGE_TYPES: dict[str, str] = {
    VISION + "ObjectHypothesis": """
string class_id
float64 score
""",
    VISION + "ObjectHypothesisWithPose": """
vision_msgs/ObjectHypothesis hypothesis
geometry_msgs/PoseWithCovariance pose
""",
    VISION + "BoundingBox3D": """
geometry_msgs/Pose center
geometry_msgs/Vector3 size
""",
    VISION + "Detection3D": """
std_msgs/Header header
vision_msgs/ObjectHypothesisWithPose[] results
vision_msgs/BoundingBox3D bbox
string id
""",
    VISION + "Detection3DArray": """
std_msgs/Header header
vision_msgs/Detection3D[] detections
""",
}
"""vision_msgs' types (4.1.1) this profile speaks, which rosbags' Jazzy typestore lacks, as `.msg` text
per type name (as autoware.MESSAGE_TYPES)."""
register_types(MESSAGE_TYPES)
T = TYPESTORE.types
DETECTIONS = "vision_msgs/msg/Detection3DArray"
DETECTIONS_TOPIC = "/perception/detections_3d"
CLASS_ID = "car"


def encode_detections(objects: Objects, stamp_ns: int, kind: str = "perception") -> bytes:
    """A frame of boxes as a Detection3DArray's CDR (`kind` unused: the type has no colour)."""
    header = msgs.header(stamp_ns)
    detections = []
    for object_id, x, y, yaw, length, width, height, score in zip(
            *(objects[name].tolist() for name in ("ids", "x", "y", "yaw", "length", "width", "height", "score"))):
        center = msgs.pose(x, y, yaw)
        hypothesis = T["vision_msgs/msg/ObjectHypothesisWithPose"](
            hypothesis=T["vision_msgs/msg/ObjectHypothesis"](class_id=CLASS_ID, score=float(score)),
            pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=center, covariance=np.zeros(36)))
        detections.append(T["vision_msgs/msg/Detection3D"](
            header=header, results=[] if math.isnan(score) else [hypothesis],
            bbox=T["vision_msgs/msg/BoundingBox3D"](center=center, size=T["geometry_msgs/msg/Vector3"](
                x=float(length), y=float(width), z=float(height))),
            id=str(object_id)))
    return bytes(TYPESTORE.serialize_cdr(T[DETECTIONS](header=header, detections=detections), DETECTIONS))


def _id(text: str, index: int) -> int:
    try:
        return int(text)
    except ValueError:
        return index


def decode_detections(data: Cdr, where: str) -> tuple[int | None, Objects]:
    msg = deserialize(data, DETECTIONS, where)
    ids, rows = [], []
    for i, item in enumerate(msg.detections):
        pose, size = item.bbox.center, item.bbox.size
        q = pose.orientation
        score = max((r.hypothesis.score for r in item.results), default=math.nan)
        ids.append(_id(item.id, i))
        rows.append((pose.position.x, pose.position.y, quaternion_yaw(q.x, q.y, q.z, q.w), 0.0, 0.0,
                     size.x, size.y, size.z, score))
    return msgs.stamp_ns(msg.header.stamp), objects_from_rows(ids, rows, where)


PROFILE = Profile(
    name="vision_msgs",
    description="detections as vision_msgs/Detection3DArray on /perception/detections_3d (no velocity); "
                "tracks, plan and ego as in advperc",
    detections=ObjectsLayer(DETECTIONS_TOPIC, DETECTIONS, encode_detections, decode_detections, import_rank=4,
                            carries_velocity=False),
    tracks=advperc.PROFILE.tracks,
    plan=advperc.PROFILE.plan,
    ego_topic=advperc.PROFILE.ego_topic,
    message_types=MESSAGE_TYPES,
)
