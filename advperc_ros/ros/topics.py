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
RECORDED_AGENTS = "/ground_truth/recorded"  # attack bags under reactive traffic: the recording the agents left

# lockstep control (advperc_ros.ros.lockstep): std_msgs/String holding JSON
ERRORS = "/attack/errors"
READY = "/attack/ready"
DONE = "/attack/done"
PRESENCE = "/attack/nodes"
REFERENCE = "/attack/reference"  # the ground truth's rollout, for the rule monitor's rules that compare with it
DELIVERED = "/attack/delivered"  # (drive: clock) the tracker's word that every reader holds a frame's tracks
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
    RECORDED_AGENTS: "visualization_msgs/msg/MarkerArray",
}
"""The data topics: what bags hold and the graph's nodes exchange per frame."""
CONTROL_TOPICS = (ERRORS, READY, DONE, PRESENCE, REFERENCE, DELIVERED)
LATCHED = frozenset({LANES, ROUTE, FOOTPRINT, SUMMARY, ERRORS, PRESENCE, REFERENCE})

DEPTH = 1000
LATCHED_DEPTH = 1

PROMPT_HEARTBEATS = ('<CycloneDDS><Domain id="any"><Internal><HeartbeatInterval min="1ms" minsched="1ms" max="10ms">'
                     '1ms</HeartbeatInterval></Internal></Domain></CycloneDDS>')
"""Cyclone DDS configuration for our nodes' processes: a writer with data not yet acknowledged asks its
readers for acknowledgements every 1 ms, where Cyclone's default waits 100 ms; so the clock drive's
wait for every reader's acknowledgement of a frame (`Publisher.wait_for_acks`) costs a round trip on
loopback (0.3-0.6 ms measured) instead of 170-180 ms."""


def with_prompt_heartbeats(uri: str | None) -> str:
    """A CYCLONEDDS_URI (a comma-separated list, which Cyclone merges) with `PROMPT_HEARTBEATS` added
    once (a node we start inherits its starter's)."""
    return uri if uri and PROMPT_HEARTBEATS in uri else ",".join(filter(None, (uri, PROMPT_HEARTBEATS)))


def depth(latched: bool, reader: bool = False) -> int:
    """History depth of a topic's writers (and its bag record), or with `reader` its readers. A
    latched writer keeps its last message for late joiners; a reader keeps every writer's: a
    message without a key is one instance, so a depth-1 reader would keep only the last of several
    latched writers' messages arriving together (every node announces itself on /attack/nodes)."""
    return LATCHED_DEPTH if latched and not reader else DEPTH
