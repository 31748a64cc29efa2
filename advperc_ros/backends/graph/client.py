"""The orchestrator's side of the lockstep protocol (docs/graph.md): send a rollout's errors,
gather what the graph publishes until the player's /attack/done and everything it implies are in."""

import time
from collections.abc import Callable
from typing import Any

import numpy as np

from advperc_ros.backends.graph.assembly import PER_FRAME, RECORDED, complete
from advperc_ros.core.perception_errors import PerceptionErrors
from advperc_ros.core.planners.base import Trajectory
from advperc_ros.exceptions import RolloutFault
from advperc_ros.ros import cdr
from advperc_ros.ros import messages as msgs
from advperc_ros.ros.interfaces.base import ObjectsLayer, PlanLayer, Profile
from advperc_ros.ros.lockstep import (
    RisingStamps,
    RolloutDone,
    RolloutErrors,
    errors_message,
    parse_done,
    parse_presence,
    parse_rule_diagnostics,
)
from advperc_ros.ros.topics import (
    CONTROL_TYPE,
    DONE,
    ERRORS,
    ODOMETRY,
    PLAN,
    PRESENCE,
    REFERENCE,
    RULE_DIAGNOSTICS,
    TOPIC_TYPES,
    TRACKING,
)
from advperc_ros.ros.transport import Transport

SPIN = 0.05  # s per transport spin while waiting; per-frame topics are taken at least this often
SETTLE = 0.001  # s per spin once /attack/done is in but per-frame messages are still due


class LockstepClient:
    """Over one transport: the /attack/errors and /attack/reference writers, readers of /attack/done, /attack/nodes and the
    per-frame topics a result needs (tracks and plans too once `record_too` was called)."""

    def __init__(self, transport: Transport, agent_ids: np.ndarray, stamps_ns: np.ndarray, stop_at_collision: bool,
                 profile: Profile) -> None:
        self.transport = transport
        # tracks and plans are read where the profile puts them, in its types; the rest is the graph's own
        self._layers: dict[str, ObjectsLayer | PlanLayer] = {TRACKING: profile.tracks, PLAN: profile.plan}
        self.present: dict[str, int] = {}  # node name -> pid, from /attack/nodes
        self.announced: dict[str, set[int]] = {}  # node name -> every pid announced under it (two graphs: two)
        self.versions: dict[str, str] = {}  # node name -> the version it announced (a team's node may)
        self.received: dict[str, dict[int, Any]] = {}  # topic -> stamp -> decoded value
        self._agent_ids = agent_ids
        self._stamps_ns = stamps_ns
        self._stamps = [int(s) for s in stamps_ns]
        self._stop_at_collision = stop_at_collision
        self._done: list[RolloutDone] = []
        self._next_rollout = 1
        self.errors = transport.publisher(ERRORS, CONTROL_TYPE, latched=True)
        self.reference = transport.publisher(REFERENCE, CONTROL_TYPE, latched=True)  # the ground truth's rollout
        for topic in PER_FRAME:
            self._subscribe(topic)
        transport.subscriber(DONE, CONTROL_TYPE, callback=lambda msg: self._done.append(parse_done(msg)))
        transport.subscriber(PRESENCE, CONTROL_TYPE, latched=True, callback=self._on_presence)

    @property
    def recording(self) -> bool:
        return all(topic in self.received for topic in RECORDED)

    def record_too(self) -> None:
        """Subscribe to tracks and plans, which only recorded rollouts need (decoding them every
        frame would slow every rollout)."""
        for topic in RECORDED:
            self._subscribe(topic)

    def _on_presence(self, msg: Any) -> None:
        name, pid, version = parse_presence(msg)
        self.present[name] = pid
        if version is not None:
            self.versions[name] = version
        self.announced.setdefault(name, set()).add(pid)

    def _subscribe(self, topic: str) -> None:
        """Keep what `topic` delivers (raw) by stamp, decoded as the result needs it. Per-frame
        messages are only read once the rollout is done, so they do not wake the spin (a wake-up
        per message would compete for the CPU with the nodes in every frame)."""
        received: dict[int, Any] = {}
        self.received[topic] = received
        stamps = RisingStamps()

        def keep(data: bytes) -> None:
            stamp, value = self._decode(topic, data)
            if stamp is None:  # a message without a stamp belongs to no frame
                return
            if stamps.restarts(stamp):  # a previous rollout's input past its last frame is not this one's
                received.clear()
            received[stamp] = value

        layer = self._layers.get(topic)
        wire, msgtype = (layer.topic, layer.msgtype) if layer is not None else (topic, TOPIC_TYPES[topic])
        self.transport.subscriber(wire, msgtype, callback=keep, raw=True, wake=False)

    def _decode(self, topic: str, data: bytes) -> tuple[int | None, Any]:
        """(stamp, value) of a payload: EgoState, (minimum, distance per agent id), tracks, or a plan's
        payload as it came (`plan` decodes it once the ego's position at its frame is in)."""
        if topic == ODOMETRY:
            return msgs.ego_from_cdr(data, ODOMETRY)
        if topic == RULE_DIAGNOSTICS:
            stamp, minimum, per_agent = parse_rule_diagnostics(data)
            return stamp, (minimum, per_agent)
        layer = self._layers[topic]
        if isinstance(layer, ObjectsLayer):
            return layer.decode(data, layer.topic)
        return cdr.header_stamp(data, layer.topic), data

    def plan(self, stamp: int) -> Trajectory:
        """The plan received for the frame stamped `stamp`, timed as the player timed it."""
        layer = self._layers[PLAN]
        assert isinstance(layer, PlanLayer)
        ego = self.received[ODOMETRY][stamp]
        return layer.decode(self.received[PLAN][stamp], self._stamps[0], (ego.x, ego.y), layer.topic)[1]

    def send(self, errors: PerceptionErrors, ahead: bool, confirmed: bool) -> int:
        """Publish a rollout's errors under a fresh rollout id, with whether the player may run the
        ground truth a frame ahead and whether our tracker confirms each frame's delivery (drive:
        clock); forget the previous rollout's messages."""
        rollout = self._next_rollout
        self._next_rollout += 1
        for received in self.received.values():
            received.clear()
        self._done.clear()
        self.errors.publish(errors_message(RolloutErrors(rollout, errors, self._agent_ids, self._stamps_ns, ahead,
                                                                 confirmed)))
        return rollout

    def collect(self, rollout: int, stall: float, record: bool, dead: Callable[[], str | None]) -> RolloutDone:
        """Spin until the player's /attack/done for `rollout` and every message it implies are in;
        a RolloutFault when a node died (`dead()` says which), the player timed out, or nothing
        came for `stall` seconds."""
        idle_since = time.monotonic()
        done = None
        while True:
            if self.transport.spin_once(SPIN if done is None else SETTLE):
                idle_since = time.monotonic()
            death = dead()
            if death is not None:
                raise RolloutFault(death)
            done = next((d for d in self._done if d.rollout == rollout), None)
            if done is not None and done.timeout:
                raise RolloutFault(done.reason, done.gone)
            if done is not None and complete(self.received, self._stamps, done, record, self._stop_at_collision):
                return done
            if time.monotonic() - idle_since > stall:
                raise RolloutFault(f"no message from the graph for {stall:g} s "
                                   "(player, injector or rule monitor dead or silent)")
