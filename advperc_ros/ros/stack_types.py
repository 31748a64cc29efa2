"""The message types of the driving stacks teams run, for rosbags and bare DDS (no ROS needed).

rosbags' Jazzy typestore knows the ROS 2 core messages but not the stacks' own: Autoware's
perception and planning messages (autoware_msgs 1.12.0) and `vision_msgs` (4.1.1). Their field
layouts are declared below in `.msg` syntax (fields and the constants this package writes; the
upstream files' comments left out) and registered into a typestore with rosbags'
`get_types_from_msg`, so bags, the CDR codecs and the bare-DDS transport speak them exactly as
rclpy does. With ROS 2 sourced, test_stack_types holds every type's bytes and RIHS01 hash to the
generated rosidl types of the upstream packages.
"""

from typing import Any

from rosbags.typesys import get_types_from_msg

AUTOWARE = "autoware_perception_msgs/msg/"
PLANNING = "autoware_planning_msgs/msg/"
VISION = "vision_msgs/msg/"

DEFINITIONS: dict[str, str] = {
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
"""`.msg` text per type name (`pkg/msg/Type`)."""


def register(typestore: Any) -> None:
    """Add the stacks' types to `typestore` (a rosbags Typestore already holding the Jazzy core)."""
    types: dict[str, Any] = {}
    for name, text in DEFINITIONS.items():
        types.update(get_types_from_msg(text, name))
    typestore.register(types)
