#!/usr/bin/env python3
"""A team's own tracker between a vision_msgs detector and the planner: nothing of advperc_ros
imported. Attack the stack with your tracker in it (the errors are injected at the detector's
output, as in the paper, and go through your tracker):

    ros2 launch advperc_ros attack.launch.py params:=config/idm_lane_following.yaml \\
        tracker:=external interface:=vision_msgs
    python3 examples/vision_tracker.py          # in another terminal, same ROS_DOMAIN_ID

Input: vision_msgs/Detection3DArray on /perception/detections_3d (box centre, size, heading; no
velocity). Output, stamped as the detections it answers: the tracked objects on /tracking/objects
as the graph's own planner reads them (visualization_msgs/MarkerArray: a DELETEALL marker first,
carrying the stamp; per track a CUBE in namespace `objects` and an ARROW in namespace `velocity`
from the centre to where it is 1 s later; docs/graph.md). One tracks message per detections
message: the planner answers each. A detections stamp at or before the last one answered starts a
new rollout: start afresh.

The tracking itself is a placeholder: greedy nearest-neighbour association within 3 m, velocity
from the last two positions (smoothed), tracks kept 0.5 s without a detection.
"""

import math

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from vision_msgs.msg import Detection3DArray
from visualization_msgs.msg import Marker, MarkerArray

GATE_M = 3.0
MAX_AGE_S = 0.5
SMOOTHING = 0.5  # weight of the newest velocity estimate

LOCKSTEP = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE)


def seconds(stamp) -> float:
    return stamp.sec + stamp.nanosec * 1e-9


class Track:
    def __init__(self, track_id: int, box, now: float) -> None:
        self.id = track_id
        self.box = box
        self.vx = self.vy = 0.0
        self.seen = now

    def update(self, box, now: float) -> None:
        dt = now - self.seen
        if dt > 0.0:
            vx = (box.center.position.x - self.box.center.position.x) / dt
            vy = (box.center.position.y - self.box.center.position.y) / dt
            self.vx += SMOOTHING * (vx - self.vx)
            self.vy += SMOOTHING * (vy - self.vy)
        self.box, self.seen = box, now

    def position(self, now: float) -> tuple[float, float]:
        """Where the track is now, moved on at its velocity since it was last seen."""
        dt = now - self.seen
        return self.box.center.position.x + self.vx * dt, self.box.center.position.y + self.vy * dt


class VisionTracker(Node):
    def __init__(self) -> None:
        super().__init__("vision_tracker")
        self.tracks: list[Track] = []
        self.next_id = 0
        self.last_stamp: float | None = None
        self.publisher = self.create_publisher(MarkerArray, "/tracking/objects", LOCKSTEP)
        self.create_subscription(Detection3DArray, "/perception/detections_3d", self.on_detections, LOCKSTEP)

    def on_detections(self, msg: Detection3DArray) -> None:
        now = seconds(msg.header.stamp)
        if self.last_stamp is not None and now <= self.last_stamp:
            self.tracks, self.next_id = [], 0  # a new rollout
        self.last_stamp = now
        unmatched = list(msg.detections)
        for track in sorted(self.tracks, key=lambda t: t.id):
            x, y = track.position(now)
            nearest = min(unmatched, default=None, key=lambda d: math.hypot(d.bbox.center.position.x - x,
                                                                           d.bbox.center.position.y - y))
            if nearest is not None and math.hypot(nearest.bbox.center.position.x - x,
                                                  nearest.bbox.center.position.y - y) < GATE_M:
                track.update(nearest.bbox, now)
                unmatched.remove(nearest)
        self.tracks = [t for t in self.tracks if now - t.seen < MAX_AGE_S - 1e-6]
        for detection in unmatched:
            self.tracks.append(Track(self.next_id, detection.bbox, now))
            self.next_id += 1
        self.publisher.publish(self.markers(msg.header, now))

    def markers(self, header, now: float) -> MarkerArray:
        clear = Marker(header=header, action=Marker.DELETEALL)
        markers = [clear]
        for track in self.tracks:
            x, y = track.position(now)
            cube = Marker(header=header, ns="objects", id=track.id, type=Marker.CUBE, action=Marker.ADD)
            cube.pose.position.x, cube.pose.position.y = x, y
            cube.pose.orientation = track.box.center.orientation
            cube.scale.x, cube.scale.y, cube.scale.z = track.box.size.x, track.box.size.y, track.box.size.z
            cube.color.g = cube.color.a = 1.0
            arrow = Marker(header=header, ns="velocity", id=track.id, type=Marker.ARROW, action=Marker.ADD)
            tail, tip = cube.pose.position.__class__(), cube.pose.position.__class__()
            tail.x, tail.y = x, y
            tip.x, tip.y = x + track.vx, y + track.vy
            arrow.points = [tail, tip]
            arrow.scale.x, arrow.scale.y, arrow.scale.z = 0.2, 0.4, 0.4
            arrow.color.g = arrow.color.a = 1.0
            markers += [cube, arrow]
        return MarkerArray(markers=markers)


def main(args=None) -> None:
    rclpy.init(args=args)
    node = None
    try:
        node = VisionTracker()
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    main()
