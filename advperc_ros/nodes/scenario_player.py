"""Node `scenario_player`: the graph's only clock; replays a ground-truth bag one frame at a time.

On /attack/ready (the injector holds rollout r's errors) it runs rollout r in lockstep:

1. publish frame k: /clock, /ground_truth/objects (the bag's own message; under reactive traffic,
   `traffic.reactive`, the agents as `core.traffic` moves them, frame k+1 from frame k and the ego's
   odometry there, as the embedded rollout moves them) and /ego/odometry, all
   stamped t_k (frame 0: the bag's own start odometry, restamped t_0). When the rollout's ready
   message says `ahead` (our tracker and planner, driven by messages), the ground truth runs one
   frame ahead of the ego: frame 0 comes with the ground truth of frame 1, and frame k with that of
   frame k+1 (published after the odometry, which the planner waits for), so that the injector and
   the tracker work on frame k+1 while the planner plans frame k. Nothing the nodes compute depends
   on the ego but the plan and the rule value, so the results are the same;
2. wait for the rule value (/rules/diagnostics stamped t_k) and the plan (/planning/trajectory
   stamped t_k); messages with other stamps are ignored. Waiting for both at every published
   frame, even when the rollout ends there, leaves no answer in flight when it ends.
   With `graph.drive: clock` (planners on timers under use_sim_time) /clock is published last
   instead, once frame k is delivered: every reader has acknowledged the odometry (and the other
   inputs of the ego the profile has), and our tracker has confirmed on /attack/delivered that every
   reader holds the tracks stamped t_k (a team's tracker confirms nothing: there, once its tracks
   reach the player). A single-threaded executor then runs the node's input callbacks before the
   timer the clock fires, so a timer that plans with whatever it holds plans on frame k; the first
   plan stamped in [t_k, t_{k+1}) is taken. A rollout starts with the clock at
   the scenario's last stamp, so that its step to t_0 is a jump back in every rollout, the first
   too: ROS timers do not fire on a jump back, so a timer-driven node must take one as the start of
   a rollout (reset, and plan once the executor has run its inputs' callbacks; docs/stacks.md);
3. exactly as `core.rollout`: stop at a rule violation if `stop_at_collision`; an empty plan (the
   planner failed) or one that does not cover t_{k+1} makes the rollout inconclusive; else move the
   ego along the plan (`core.rollout.after_plan`, the embedded rollout's rule) and publish frame k+1;
4. publish /attack/done. If the rule value or plan of a frame does not come within `graph.timeout`
   seconds the rollout is inconclusive (`timeout: true`), never a pass or a failure.

The latched /map/lanes and /ego/route are the bag's own messages, published at start, with the
latched /ego/footprint: the ego's box (`ego.length` x `ego.width`) around its reference point.
"""

import dataclasses
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from advperc_ros.configs import traffic_model
from advperc_ros.core.planners.base import Trajectory
from advperc_ros.core.rollout import after_plan, violates
from advperc_ros.core.traffic import IDMParameters, ReactiveTraffic, RecordedPaths
from advperc_ros.exceptions import MessageTypeMissing
from advperc_ros.nodes.runtime import Logger, NodeSpec, run_node
from advperc_ros.params import TRAFFIC_PARAMS
from advperc_ros.ros import cdr
from advperc_ros.ros import messages as msgs
from advperc_ros.ros.bag import read_scenario, read_topics
from advperc_ros.ros.interfaces.base import Profile
from advperc_ros.ros.interfaces.registry import load_profile
from advperc_ros.ros.lockstep import (
    RolloutDone,
    Status,
    done_message,
    parse_delivered,
    parse_ready,
    parse_rule_diagnostics,
)
from advperc_ros.ros.topics import (
    CLOCK,
    CONTROL_TYPE,
    DELIVERED,
    DONE,
    FOOTPRINT,
    GROUND_TRUTH,
    LANES,
    LATCHED,
    ODOMETRY,
    READY,
    ROUTE,
    RULE_DIAGNOSTICS,
    TOPIC_TYPES,
)
from advperc_ros.ros.transport import Publisher, Transport


@dataclass
class _Run:
    rollout: int
    frame: int
    deadline: float
    ahead: bool = False  # the ground truth runs one frame ahead of the ego (the ready message's word)
    ego_xy: tuple[float, float] = (0.0, 0.0)  # where the ego is at this frame (a plan without times is timed from it)
    speed: float = 0.0  # the ego's speed at this frame (its change is the acceleration a stack may read)
    clocked: bool = True  # /clock shows this frame's time (drive: clock sets it once the frame is delivered)
    confirmed: bool = False  # (drive: clock) our tracker confirms each frame's tracks on /attack/delivered
    rule: float | None = None
    plan: Trajectory | None = None
    stray: int | None = None  # the last plan stamp this frame that no frame of the scenario bears (wall time?)


class ScenarioPlayer:
    """The player's logic without its process, built on any Transport: the graph's clock and the
    judge of every frame, which alone decides when a rollout ends and why."""

    def __init__(self, transport: Transport, bag: Path, stop_at_collision: bool, timeout: float, profile: Profile,
                 by_clock: bool, logger: Logger, ego_size: tuple[float, float],
                 traffic: IDMParameters | None = None) -> None:
        """`traffic`: the reactive agents' driver model (None: the agents replay the bag)."""
        self.scenario = read_scenario(bag)
        self._traffic_model = traffic
        self._ego_size = ego_size
        self._paths = None if traffic is None else RecordedPaths(self.scenario.agents)
        self._traffic: ReactiveTraffic | None = None
        self._transport = transport
        self._frame_stamps = frozenset(int(stamp) for stamp in self.scenario.stamps_ns)
        self._plan_layer = profile.plan
        self._tracks_layer = profile.tracks
        self._by_clock = by_clock
        self._stop_at_collision = stop_at_collision
        self._timeout = timeout
        self._log = logger
        # the bag's own messages as stored (CDR): the same bytes go out in every rollout
        topics, _ = read_topics(bag, [GROUND_TRUTH, ODOMETRY, LANES, ROUTE], raw=True)
        by_stamp = {cdr.decode_objects(data, GROUND_TRUTH)[0]: data for _, data in topics[GROUND_TRUTH]}
        self._ground_truth = [by_stamp[int(stamp)] for stamp in self.scenario.stamps_ns]
        start: Any = msgs.TYPESTORE.deserialize_cdr(topics[ODOMETRY][0][1], TOPIC_TYPES[ODOMETRY])  # an Odometry
        restamped = dataclasses.replace(start, header=msgs.header(int(self.scenario.stamps_ns[0])))
        self._start = cdr.payload(restamped, TOPIC_TYPES[ODOMETRY])
        self._run: _Run | None = None
        self._pub = {topic: transport.publisher(topic, TOPIC_TYPES[topic], latched=topic in LATCHED)
                     for topic in (CLOCK, GROUND_TRUTH, ODOMETRY, LANES, ROUTE, FOOTPRINT)}
        self._pub[FOOTPRINT].publish(msgs.footprint_cdr(*ego_size, int(self.scenario.stamps_ns[0])))
        # the rule monitor reads /ego/odometry; a stack reads its own topic, where the same message goes too
        self._ego = [self._pub[ODOMETRY]] + ([transport.publisher(profile.ego_topic, TOPIC_TYPES[ODOMETRY])]
                                             if profile.ego_topic != ODOMETRY else [])
        self._acceleration = self._optional(transport, profile.acceleration_topic, msgs.ACCELERATION)
        self._transforms = self._optional(transport, profile.transforms_topic, msgs.TRANSFORMS)
        self._ego_inputs = [publisher for publisher in (*self._ego, self._acceleration, self._transforms)
                            if publisher is not None]  # what a stack reads of the ego, delivered before the clock
        self._done = transport.publisher(DONE, CONTROL_TYPE)
        for topic in (LANES, ROUTE):
            if topics[topic]:
                self._pub[topic].publish(topics[topic][0][1])
        transport.subscriber(READY, CONTROL_TYPE, callback=self.on_ready)
        transport.subscriber(profile.plan.topic, profile.plan.msgtype, callback=self.on_plan, raw=True)
        if by_clock:
            transport.subscriber(profile.tracks.topic, profile.tracks.msgtype, callback=self.on_tracks, raw=True)
            transport.subscriber(DELIVERED, CONTROL_TYPE, callback=self.on_delivered)
        transport.subscriber(RULE_DIAGNOSTICS, TOPIC_TYPES[RULE_DIAGNOSTICS], callback=self.on_rule, raw=True)

    def _optional(self, transport: Transport, topic: str | None, msgtype: str) -> Publisher | None:
        """A publisher of a topic the profile's stack reads besides the contract, or None: where the profile
        has no such topic, or where this ROS 2 lacks the type's Python package (said once, as a warning)."""
        if topic is None:
            return None
        try:
            return transport.publisher(topic, msgtype)
        except MessageTypeMissing as missing:
            self._log.warning(f"{topic} is not published: {missing}")
            return None

    def _stamp(self, frame: int) -> int:
        return int(self.scenario.stamps_ns[frame])

    def _running(self) -> "_Run":
        """The rollout in progress (a frame is published, stepped or finished only within one)."""
        if self._run is None:
            raise RuntimeError("no rollout in progress")
        return self._run

    def _publish_frame(self, frame: int, odometry: bytes) -> None:
        run = self._running()
        stamp = self._stamp(frame)
        if not self._by_clock:
            self._pub[CLOCK].publish(cdr.encode_clock(stamp))
        elif frame == 0:
            self._pub[CLOCK].publish(cdr.encode_clock(self._stamp(-1)))
        if frame == 0 or not run.ahead:  # ahead, frame k's ground truth went out with frame k-1
            self._pub[GROUND_TRUTH].publish(self._truth(frame))
        for publisher in self._ego:
            publisher.publish(odometry)
        ego = msgs.ego_from_cdr(odometry, ODOMETRY)[1]
        if self._acceleration is not None:  # the speed's change over the last frame (0 at the start)
            rate = 0.0 if frame == 0 else (ego.v - run.speed) / ((stamp - self._stamp(frame - 1)) * 1e-9)
            self._acceleration.publish(msgs.acceleration_cdr(rate, stamp))
        if self._transforms is not None:
            self._transforms.publish(msgs.transform_cdr(ego, stamp))
        run.speed = ego.v
        run.frame = frame
        run.clocked = not self._by_clock
        run.ego_xy = (ego.x, ego.y)
        run.rule = run.plan = run.stray = None
        run.deadline = time.monotonic() + self._timeout
        if self._traffic is not None and frame + 1 < self.scenario.num_frames:
            self._traffic.advance(frame, ego)  # frame k+1's agents answer the ego at frame k
        if run.ahead and frame + 1 < self.scenario.num_frames:
            self._pub[GROUND_TRUTH].publish(self._truth(frame + 1))

    def _truth(self, frame: int) -> bytes:
        """The ground truth of `frame`: the bag's own message, or the reactive agents' frame encoded alike."""
        if self._traffic is None:
            return self._ground_truth[frame]
        return cdr.encode_objects(self._traffic.agents.frame(frame), self._stamp(frame), "ground_truth")

    def on_ready(self, msg: Any) -> None:
        ready = parse_ready(msg)
        if self._run is not None:
            self._finish(Status.INCONCLUSIVE, f"frame {self._run.frame}: superseded by rollout {ready.rollout}",
                         timeout=True)
        self._run = _Run(ready.rollout, 0, 0.0, ahead=ready.ahead, confirmed=ready.confirmed)
        if self._paths is not None and self._traffic_model is not None:
            self._traffic = ReactiveTraffic(self._paths, self._traffic_model, self.scenario.dt, self._ego_size)
        self._publish_frame(0, self._start)

    def on_tracks(self, data: bytes) -> None:
        """(drive: clock, a team's tracker) The frame's tracked objects are out: advance /clock."""
        run = self._run
        if run is None or run.clocked or run.confirmed:
            return
        if self._tracks_layer.decode(data, self._tracks_layer.topic)[0] == self._stamp(run.frame):
            self._advance_clock(run)

    def on_delivered(self, msg: Any) -> None:
        """(drive: clock, our tracker) Every reader holds the frame's tracks: advance /clock."""
        run = self._run
        if run is None or run.clocked or not run.confirmed:
            return
        delivered = parse_delivered(msg)
        if delivered.topic == self._tracks_layer.topic and delivered.stamp_ns == self._stamp(run.frame):
            self._advance_clock(run)

    def _advance_clock(self, run: _Run) -> None:
        """(drive: clock) /clock to the frame's time, once every reader holds the ego's inputs too."""
        stamp = self._stamp(run.frame)
        if not all(publisher.wait_for_acks(self._timeout) for publisher in self._ego_inputs):
            self._finish(Status.INCONCLUSIVE, f"frame {run.frame}: the ego's inputs stamped {stamp} were not acknowledged "
                                              f"by every reader within {self._timeout:g} s (a node is hung)", timeout=True)
            return
        run.clocked = True
        self._pub[CLOCK].publish(cdr.encode_clock(stamp))
        self._step()  # a message-driven planner's plan may have come first

    def on_plan(self, data: bytes) -> None:
        run = self._run
        if run is None or run.plan is not None:
            return
        stamp, plan = self._plan_layer.decode(data, self._stamp(0), run.ego_xy, self._plan_layer.topic)
        frame_stamp = self._stamp(run.frame)
        following = self._stamp(run.frame + 1) if run.frame + 1 < self.scenario.num_frames else None
        if stamp == frame_stamp or (self._by_clock and frame_stamp < stamp and (following is None or stamp < following)):
            run.plan = plan
            self._step()
        elif stamp not in self._frame_stamps and not (self._by_clock and self._stamp(0) <= stamp <= self._stamp(-1)):
            run.stray = stamp  # between frames is a timer's plan under drive: clock

    def on_rule(self, data: bytes) -> None:
        if self._run is None:
            return
        stamp, minimum, _ = parse_rule_diagnostics(data)
        if stamp == self._stamp(self._run.frame):
            self._run.rule = minimum
            self._step()

    def _step(self) -> None:
        run = self._running()
        if run.rule is None or run.plan is None or not run.clocked:
            return
        k = run.frame
        if violates(run.rule, self._stop_at_collision):
            self._finish(Status.OK, collided=True)
            return
        following = after_plan(run.plan, k, self.scenario.times)
        if following.inconclusive is not None:
            self._finish(Status.INCONCLUSIVE, following.inconclusive)
        elif following.ego is None:  # done
            self._finish(Status.OK)
        else:
            self._publish_frame(k + 1, msgs.ego_to_cdr(following.ego, self._stamp(k + 1)))

    def poll(self) -> None:
        """Called periodically: a frame unanswered past its deadline ends the rollout."""
        run = self._run
        if run is None or time.monotonic() < run.deadline:
            return
        missing = " and ".join(what for what, got in (("rule value", run.rule), ("tracked objects", run.clocked or None),
                                                      ("plan", run.plan)) if got is None)
        gone = self._gone(run)
        why = f"({gone})" if gone else "(a node is dead or silent)" if run.plan is not None or run.stray is None else \
            stray_stamps(run.stray, self._stamp(run.frame), self.scenario.stamps_ns)
        self._finish(Status.INCONCLUSIVE, f"frame {run.frame}: no {missing} stamped {self._stamp(run.frame)} within "
                                   f"{self._timeout:g} s {why}", timeout=True, gone=gone)

    def _gone(self, run: _Run) -> str:
        """What a frame waited on that no node publishes any more (its process ended, or its DDS lease did):
        the plans, or under the clock drive a team's tracks; "" while each has a publisher."""
        waited = [("plans", self._plan_layer.topic)] if run.plan is None else []
        if not run.clocked and not run.confirmed:
            waited.append(("tracked objects", self._tracks_layer.topic))
        for what, topic in waited:
            if self._transport.publisher_count(topic) == 0:
                return f"no node publishes {what} on {topic} (never started, ended, or left the DDS domain)"
        return ""

    def _finish(self, status: Status, reason: str = "", timeout: bool = False, collided: bool = False,
                gone: str = "") -> None:
        run = self._running()
        done = RolloutDone(run.rollout, run.frame + 1, status, reason, timeout, gone)
        ended = "stopped at a collision" if collided else "driven to its end" if status == Status.OK else str(status)
        line = f"rollout {run.rollout}: {done.frames} frames, {ended}" + (f": {reason}" if reason else "")
        # one call site per severity: rclpy's logger raises when a call site changes its severity
        if status == Status.OK:
            self._log.info(line)
        else:
            self._log.warning(line)
        self._run = None
        self._done.publish(done_message(done))


WALL_CLOCK_NEAR = 86400e9  # ns: a stamp within a day of the wall clock's time is taken for wall time


def stray_stamps(stray: int, expected: int, stamps_ns: Any) -> str:
    """Why a frame's plan never came though plans did: they came under stamps of another clock
    (a node without use_sim_time stamps wall time, whatever /clock says), named by one of them."""
    said = (f"(plans arrive stamped {stray} ({stray * 1e-9:.1f} s), none of the scenario's frames, "
            f"while the clock is at {expected * 1e-9:.1f} s")
    if abs(stray - time.time_ns()) < WALL_CLOCK_NEAR and not int(stamps_ns[0]) <= stray <= int(stamps_ns[-1]):
        return said + ": the wall clock's time; is use_sim_time set on the node publishing them?)"
    return said + ": a plan must carry the stamp of the inputs it answers)"


def _build(transport: Transport, values: dict[str, Any], planner_params: dict[str, Any], logger: Logger) -> ScenarioPlayer:
    return ScenarioPlayer(transport, values["bag"], values["stop_at_collision"], values["graph.timeout"],
                          load_profile(values["graph.interface"]), values["graph.drive"] == "clock", logger,
                          (values["ego.length"], values["ego.width"]), traffic_model(values))


SPEC = NodeSpec("scenario_player", ("bag", "stop_at_collision", "graph.timeout", "graph.interface", "graph.drive",
                                    "ego.length", "ego.width", *TRAFFIC_PARAMS), _build, waits_for_acks=True)


def main(args: list[str] | None = None) -> int:
    return run_node(SPEC, args)


if __name__ == "__main__":
    sys.exit(main())
