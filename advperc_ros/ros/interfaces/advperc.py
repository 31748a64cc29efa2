"""The graph's own interface: boxes as `visualization_msgs/MarkerArray` (the convention of
`advperc_ros.ros.cdr`, which any ROS viewer draws), the plan as `nav_msgs/Path` with every pose
stamped, the ego on /ego/odometry. Every conversion is exact."""

from advperc_ros.core.planners.base import Trajectory
from advperc_ros.ros import cdr
from advperc_ros.ros import messages as msgs
from advperc_ros.ros.cdr import Cdr
from advperc_ros.ros.interfaces.base import ObjectsLayer, PlanLayer, Profile
from advperc_ros.ros.lockstep import plan_from_cdr
from advperc_ros.ros.topics import ODOMETRY, PERCEPTION, PLAN, TOPIC_TYPES, TRACKING


def decode_path(data: Cdr, first_stamp_ns: int, ego_xy: tuple[float, float], where: str) -> tuple[int, Trajectory]:
    """A Path's poses carry their own stamps: the ego's position is not needed to time them."""
    return plan_from_cdr(data, first_stamp_ns, where)


PROFILE = Profile(
    name="advperc",
    description="this package's own: MarkerArray boxes on /perception/objects and /tracking/objects, "
                "nav_msgs/Path plans on /planning/trajectory, Odometry on /ego/odometry",
    detections=ObjectsLayer(PERCEPTION, TOPIC_TYPES[PERCEPTION], cdr.encode_objects, cdr.decode_objects,
                            import_rank=2),
    tracks=ObjectsLayer(TRACKING, TOPIC_TYPES[TRACKING], cdr.encode_objects, cdr.decode_objects, import_rank=2),
    plan=PlanLayer(PLAN, TOPIC_TYPES[PLAN], msgs.trajectory_cdr, decode_path),
    ego_topic=ODOMETRY,
)
