"""The topic contract in one place: every topic's name, message type and QoS.

docs/graph.md's topic table states the same, and test/nodes/test_ros2.py holds the live graph to it. QoS
is one rule on every transport and in bags: reliable; volatile keep-last `DEPTH`, or latched
(transient-local, writers keep-last `LATCHED_DEPTH`), which is what ROS 2 calls latching.
"""

from advperc_ros.core.rules.registry import RULES

CLOCK = "/clock"
GROUND_TRUTH = "/ground_truth/objects"
PERCEPTION = "/perception/objects"
TRACKING = "/tracking/objects"
ODOMETRY = "/ego/odometry"
PLAN = "/planning/trajectory"
RULE_TOPICS = {name: f"/rules/{name}" for name in RULES}
"""Each rule of the rulebook's value per frame (std_msgs/Float64, r < 0 a violation), on a topic of its own."""
RULE = RULE_TOPICS["collision"]  # the minimum signed distance: what the player waits on, with the diagnostics
RULE_DIAGNOSTICS = "/rules/diagnostics"
LANES = "/map/lanes"
ROUTE = "/ego/route"
FOOTPRINT = "/ego/footprint"  # the ego's box around its reference point (the odometry's pose)
SUMMARY = "/attack/summary"  # attack bags only

# lockstep control (advperc_ros.ros.lockstep): std_msgs/String holding JSON
ERRORS = "/attack/errors"
READY = "/attack/ready"
DONE = "/attack/done"
PRESENCE = "/attack/nodes"
REFERENCE = "/attack/reference"  # the ground truth's rollout, for the rule monitor's rules that compare with it
CONTROL_TYPE = "std_msgs/msg/String"

TOPIC_TYPES = {
    CLOCK: "rosgraph_msgs/msg/Clock",
    GROUND_TRUTH: "visualization_msgs/msg/MarkerArray",
    PERCEPTION: "visualization_msgs/msg/MarkerArray",
    TRACKING: "visualization_msgs/msg/MarkerArray",
    ODOMETRY: "nav_msgs/msg/Odometry",
    PLAN: "nav_msgs/msg/Path",
    **dict.fromkeys(RULE_TOPICS.values(), "std_msgs/msg/Float64"),
    RULE_DIAGNOSTICS: "diagnostic_msgs/msg/DiagnosticArray",
    LANES: "visualization_msgs/msg/MarkerArray",
    ROUTE: "nav_msgs/msg/Path",
    FOOTPRINT: "geometry_msgs/msg/PolygonStamped",
    SUMMARY: "std_msgs/msg/String",
}
"""The data topics: what bags hold and the graph's nodes exchange per frame."""
CONTROL_TOPICS = (ERRORS, READY, DONE, PRESENCE, REFERENCE)
LATCHED = frozenset({LANES, ROUTE, FOOTPRINT, SUMMARY, ERRORS, PRESENCE, REFERENCE})

DEPTH = 1000
LATCHED_DEPTH = 1


def depth(latched: bool, reader: bool = False) -> int:
    """History depth of a topic's writers (and its bag record), or with `reader` its readers. A
    latched writer keeps its last message for late joiners; a reader keeps every writer's: a
    message without a key is one instance, so a depth-1 reader would keep only the last of several
    latched writers' messages arriving together (every node announces itself on /attack/nodes)."""
    return LATCHED_DEPTH if latched and not reader else DEPTH
