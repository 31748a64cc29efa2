#!/usr/bin/env python3
"""A planner node as an Autoware team writes one: a 10 Hz timer under `use_sim_time`, Autoware's
messages in and out, nothing of advperc_ros imported. Attack it with:

    ros2 launch advperc_ros attack.launch.py params:=config/idm_lane_following.yaml \\
        planner:=external interface:=autoware drive:=clock
    python3 examples/autoware_planner.py        # in another terminal, same ROS_DOMAIN_ID

Inputs: autoware_perception_msgs/PredictedObjects on /perception/object_recognition/objects,
nav_msgs/Odometry on /localization/kinematic_state (in this graph the pose is the centre of the
ego's box, not Autoware's rear axle) and the route as a latched nav_msgs/Path on /ego/route (the
graph has no Lanelet2 map). Output: autoware_planning_msgs/Trajectory on
/planning/scenario_planning/trajectory, sampled every metre along the route from 2 m behind the
ego, `time_from_start` left 0 as Autoware's planners leave it, the speed in
`longitudinal_velocity_mps`. It announces its build on the latched /attack/nodes (optional), so the
attack's report says which version of it was attacked.

What a timer-driven node does under the graph's clock (docs/stacks.md, "Driving the planner") is what
it does on a car: plan on every tick with the latest inputs it holds, stamp the trajectory with the
clock's time, and take a jump of the clock back as a restart, as ROS nodes do (tf clears its buffer
on one). ROS timers do not fire on a jump back, so the restart plans once the executor has run the
callbacks of the inputs that came with it: the jump callback triggers a guard condition rather than
planning itself (it runs inside the /clock callback, before the others of its wait). The clock drive
delivers each frame's inputs before its clock, so every tick plans on its own frame and the attack
replays (`reproduced: true`).

The planning itself is a placeholder, an adaptive cruise control along the route: cruise at the
speed limit, follow the nearest predicted object ahead within the lane at a time gap.
"""

import json
import math
import os

import numpy as np
import rclpy
from autoware_perception_msgs.msg import PredictedObjects
from autoware_planning_msgs.msg import Trajectory, TrajectoryPoint
from nav_msgs.msg import Odometry, Path
from rclpy.clock import JumpThreshold
from rclpy.duration import Duration
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import String

VERSION = "acc-0.4"  # this build: the attack's report names it and its config_hash covers it
PERIOD_S = 0.1
HORIZON_S = 8.0
SAMPLE_M = 1.0
BEHIND_M = 2.0
SPEED_LIMIT = 14.0  # m/s
TIME_GAP_S = 1.4
STANDSTILL_M = 4.0  # bumper to bumper
MAX_ACCEL, MAX_DECEL = 1.5, 6.0  # m/s^2
EGO_LENGTH_M = 4.6
LANE_HALF_WIDTH_M = 1.8

RELIABLE = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE)
LATCHED = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)


def yaw_of(q) -> float:
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


class Route:
    """The route as a polyline with arc lengths: projection and interpolation along it."""

    def __init__(self, xy: np.ndarray) -> None:
        keep = np.append(True, np.hypot(*np.diff(xy, axis=0).T) > 1e-6)
        self.xy = xy[keep]
        self.s = np.concatenate(([0.0], np.cumsum(np.hypot(*np.diff(self.xy, axis=0).T))))

    def project(self, x: float, y: float) -> tuple[float, float]:
        """(arc length, signed lateral offset) of a point's foot on the route."""
        a, b = self.xy[:-1], self.xy[1:]
        d = b - a
        u = np.clip(((x - a[:, 0]) * d[:, 0] + (y - a[:, 1]) * d[:, 1]) / (d ** 2).sum(axis=1), 0.0, 1.0)
        foot = a + u[:, None] * d
        i = int(np.argmin(np.hypot(foot[:, 0] - x, foot[:, 1] - y)))
        lateral = (d[i, 0] * (y - a[i, 1]) - d[i, 1] * (x - a[i, 0])) / math.hypot(*d[i])
        return float(self.s[i] + u[i] * math.hypot(*d[i])), float(lateral)

    def pose(self, s: float) -> tuple[float, float, float]:
        """x, y and heading at arc length s (the ends extended along their segments)."""
        i = int(np.clip(np.searchsorted(self.s, s) - 1, 0, len(self.s) - 2))
        d = self.xy[i + 1] - self.xy[i]
        u = (s - self.s[i]) / (self.s[i + 1] - self.s[i])
        x, y = self.xy[i] + u * d
        return float(x), float(y), math.atan2(d[1], d[0])


class AutowareStylePlanner(Node):
    def __init__(self) -> None:
        super().__init__("autoware_style_planner", parameter_overrides=[Parameter("use_sim_time", value=True)])
        self.route: Route | None = None
        self.odometry: Odometry | None = None
        self.objects: PredictedObjects | None = None
        self.trajectory = self.create_publisher(Trajectory, "/planning/scenario_planning/trajectory", RELIABLE)
        self.create_subscription(Path, "/ego/route", self.on_route, LATCHED)
        self.create_subscription(Odometry, "/localization/kinematic_state", self.on_odometry, RELIABLE)
        self.create_subscription(PredictedObjects, "/perception/object_recognition/objects", self.on_objects, RELIABLE)
        self.create_timer(PERIOD_S, self.on_timer)
        # optional: say which build this is (the latched /attack/nodes, depth 1000 for its readers)
        self.presence = self.create_publisher(String, "/attack/nodes", LATCHED)
        self.presence.publish(String(data=json.dumps({"node": self.get_name(), "pid": os.getpid(), "version": VERSION})))
        # a jump of the clock back is a restart: timers do not fire on it, so plan once the executor has
        # delivered the inputs that came with it (a guard condition is taken after this wait's callbacks)
        self.restart = self.create_guard_condition(self.on_timer)
        self.jump = self.get_clock().create_jump_callback(
            JumpThreshold(min_forward=None, min_backward=Duration(nanoseconds=-1), on_clock_change=False),
            post_callback=self.on_jump_back)

    def on_route(self, msg: Path) -> None:
        self.route = Route(np.array([[p.pose.position.x, p.pose.position.y] for p in msg.poses]))

    def on_odometry(self, msg: Odometry) -> None:
        self.odometry = msg

    def on_objects(self, msg: PredictedObjects) -> None:
        self.objects = msg

    def on_jump_back(self, jump) -> None:
        # (resetting the timer here would deadlock: the callback runs under the clock's lock)
        self.restart.trigger()

    def on_timer(self) -> None:
        now = self.get_clock().now()
        if self.route is None or self.odometry is None or self.objects is None:
            return
        self.trajectory.publish(self.plan(now.to_msg()))

    def lead(self, s_ego: float) -> tuple[float, float] | None:
        """(bumper-to-bumper gap, speed along the route) of the nearest object ahead in the lane."""
        best = None
        for obj in self.objects.objects:
            pose = obj.kinematics.initial_pose_with_covariance.pose
            s, lateral = self.route.project(pose.position.x, pose.position.y)
            if s <= s_ego or abs(lateral) > LANE_HALF_WIDTH_M:
                continue
            _, _, heading = self.route.pose(s)
            twist = obj.kinematics.initial_twist_with_covariance.twist.linear
            speed = twist.x * math.cos(yaw_of(pose.orientation) - heading)
            gap = s - s_ego - (EGO_LENGTH_M + obj.shape.dimensions.x) / 2.0
            if best is None or gap < best[0]:
                best = (gap, speed)
        return best

    def plan(self, stamp) -> Trajectory:
        ego = self.odometry.pose.pose.position
        s_ego, _ = self.route.project(ego.x, ego.y)
        v = max(self.odometry.twist.twist.linear.x, 0.0)
        lead = self.lead(s_ego)
        # speed profile over the horizon: ACC on the lead (moving at its current speed), else cruise
        s, speeds, travelled = s_ego, [(s_ego, v)], 0.0
        gap, lead_speed = lead if lead is not None else (math.inf, 0.0)
        for _ in range(int(HORIZON_S / PERIOD_S)):
            if math.isfinite(gap):
                accel = 0.3 * (gap - STANDSTILL_M - TIME_GAP_S * v) + 0.8 * (lead_speed - v)
            else:
                accel = 0.5 * (SPEED_LIMIT - v)
            accel = min(max(accel, -MAX_DECEL), MAX_ACCEL)
            v_next = max(v + accel * PERIOD_S, 0.0)
            step = 0.5 * (v + v_next) * PERIOD_S
            if step <= 0.0:  # stopped: the points beyond carry speed 0
                break
            s += step
            gap += (lead_speed * PERIOD_S) - step
            v = v_next
            speeds.append((s, v))
        profile = np.array(speeds)
        trajectory = Trajectory()
        trajectory.header.stamp = stamp
        trajectory.header.frame_id = "map"
        for s_point in np.arange(s_ego - BEHIND_M, max(profile[-1, 0], s_ego) + SAMPLE_M, SAMPLE_M):
            x, y, heading = self.route.pose(float(s_point))
            point = TrajectoryPoint()
            point.pose.position.x, point.pose.position.y = x, y
            point.pose.orientation.z, point.pose.orientation.w = math.sin(heading / 2.0), math.cos(heading / 2.0)
            point.longitudinal_velocity_mps = float(np.interp(s_point, profile[:, 0], profile[:, 1]))
            trajectory.points.append(point)
        return trajectory


def main(args=None) -> None:
    rclpy.init(args=args)
    node = None
    try:
        node = AutowareStylePlanner()
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    main()
