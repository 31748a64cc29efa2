#!/usr/bin/env python3
"""A minimal external planner honouring advperc_ros's planner contract (docs/graph.md). Copy it,
replace `plan()` with your planner, and run it instead of ours:

    ros2 launch advperc_ros attack.launch.py params:=config/idm_lane_following.yaml planner:=external
    python3 examples/external_planner.py        # in another terminal, same ROS_DOMAIN_ID

The contract, in short: answer every /tracking/objects message with one nav_msgs/Path on
/planning/trajectory stamped the same, once the /ego/odometry of that stamp is in too; stamp every
pose with its own time and cover at least the next frame; reliable QoS, keep-last 1000. A message
stamped at or before the last one you answered starts a new rollout: reset your state. If you
cannot plan, publish an empty Path with that stamp (the rollout is then inconclusive, not failed).

This planner drives along the route (latched /ego/route) at the ego's current speed and brakes at
3 m/s^2 when a track lies within 30 m ahead near the route: a placeholder, not a good planner.
"""

import math

import rclpy
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Odometry, Path
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from visualization_msgs.msg import Marker, MarkerArray

HORIZON_S = 3.0
STEP_S = 0.1
BRAKE = 3.0  # m/s^2
LOOKAHEAD_M = 30.0
CORRIDOR_M = 1.5  # lateral distance from the route that counts as "in the way"

LOCKSTEP = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE)
LATCHED = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)


def nanoseconds(stamp) -> int:
    return stamp.sec * 1_000_000_000 + stamp.nanosec


def objects_stamp(msg: MarkerArray) -> int | None:
    """A tracks MarkerArray's stamp: that of its first marker (a DELETEALL)."""
    return nanoseconds(msg.markers[0].header.stamp) if msg.markers else None


class ExternalPlanner(Node):
    def __init__(self) -> None:
        super().__init__("external_planner")
        self.route: list[tuple[float, float]] = []
        self.tracks: dict[int, MarkerArray] = {}
        self.odometry: dict[int, Odometry] = {}
        self.last_answered: int | None = None
        self.plans = self.create_publisher(Path, "/planning/trajectory", LOCKSTEP)
        self.create_subscription(Path, "/ego/route", self.on_route, LATCHED)
        self.create_subscription(MarkerArray, "/tracking/objects", self.on_tracks, LOCKSTEP)
        self.create_subscription(Odometry, "/ego/odometry", self.on_odometry, LOCKSTEP)

    def on_route(self, msg: Path) -> None:
        self.route = [(p.pose.position.x, p.pose.position.y) for p in msg.poses]

    def on_tracks(self, msg: MarkerArray) -> None:
        stamp = objects_stamp(msg)
        if stamp is not None:
            self.store(self.tracks, stamp, msg)

    def on_odometry(self, msg: Odometry) -> None:
        self.store(self.odometry, nanoseconds(msg.header.stamp), msg)

    def store(self, buffer: dict, stamp: int, msg) -> None:
        if self.last_answered is not None and stamp <= self.last_answered:
            self.reset()
        buffer[stamp] = msg
        if stamp in self.tracks and stamp in self.odometry:
            self.answer(stamp, self.tracks.pop(stamp), self.odometry.pop(stamp))

    def reset(self) -> None:
        """A new rollout: forget everything of the previous one (your planner's state too)."""
        self.tracks.clear()
        self.odometry.clear()
        self.last_answered = None

    def answer(self, stamp: int, tracks: MarkerArray, odometry: Odometry) -> None:
        self.last_answered = stamp
        path = Path()
        path.header.stamp = odometry.header.stamp
        path.header.frame_id = "map"
        try:
            path.poses = self.plan(stamp, tracks, odometry)
        except Exception as exc:  # answer anyway: an empty plan makes the rollout inconclusive
            self.get_logger().error(f"planning failed at stamp {stamp}: {exc}")
        self.plans.publish(path)

    def plan(self, stamp: int, tracks: MarkerArray, odometry: Odometry) -> list[PoseStamped]:
        if len(self.route) < 2:
            raise RuntimeError("no /ego/route received yet")
        ego = odometry.pose.pose.position
        speed = max(odometry.twist.twist.linear.x, 0.0)
        s0, heading = self.project(ego.x, ego.y)
        blocked = any(self.ahead(s0, m) for m in tracks.markers if m.ns == "objects" and m.action == Marker.ADD)
        poses, s, v = [], s0, speed
        for i in range(int(round(HORIZON_S / STEP_S)) + 1):
            x, y, heading = self.point(s)
            pose = PoseStamped()
            t = stamp + int(round(i * STEP_S * 1e9))
            pose.header.stamp.sec, pose.header.stamp.nanosec = divmod(t, 1_000_000_000)
            pose.header.frame_id = "map"
            pose.pose.position.x, pose.pose.position.y = x, y
            pose.pose.orientation.z, pose.pose.orientation.w = math.sin(heading / 2.0), math.cos(heading / 2.0)
            poses.append(pose)
            v_next = max(v - BRAKE * STEP_S, 0.0) if blocked else v
            s += 0.5 * (v + v_next) * STEP_S
            v = v_next
        return poses

    def ahead(self, s_ego: float, cube: Marker) -> bool:
        s, _ = self.project(cube.pose.position.x, cube.pose.position.y)
        x, y, _ = self.point(s)
        lateral = math.hypot(cube.pose.position.x - x, cube.pose.position.y - y)
        return 0.0 < s - s_ego < LOOKAHEAD_M and lateral < CORRIDOR_M

    def segments(self):
        s = 0.0
        for (x0, y0), (x1, y1) in zip(self.route, self.route[1:]):
            length = math.hypot(x1 - x0, y1 - y0)
            if length > 0.0:
                yield s, x0, y0, x1, y1, length
                s += length

    def project(self, x: float, y: float) -> tuple[float, float]:
        """Arc length along the route of the nearest route point, and the route heading there."""
        best = (math.inf, 0.0, 0.0)
        for s, x0, y0, x1, y1, length in self.segments():
            u = min(max(((x - x0) * (x1 - x0) + (y - y0) * (y1 - y0)) / length**2, 0.0), 1.0)
            distance = math.hypot(x - x0 - u * (x1 - x0), y - y0 - u * (y1 - y0))
            if distance < best[0]:
                best = (distance, s + u * length, math.atan2(y1 - y0, x1 - x0))
        return best[1], best[2]

    def point(self, s: float) -> tuple[float, float, float]:
        """Route point and heading at arc length s (the last segment extended)."""
        last = None
        for s0, x0, y0, x1, y1, length in self.segments():
            last = (s0, x0, y0, x1, y1, length)
            if s <= s0 + length:
                break
        s0, x0, y0, x1, y1, length = last
        u = (s - s0) / length
        return x0 + u * (x1 - x0), y0 + u * (y1 - y0), math.atan2(y1 - y0, x1 - x0)


def main(args=None) -> None:
    rclpy.init(args=args)
    node = None
    try:
        node = ExternalPlanner()
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    main()
