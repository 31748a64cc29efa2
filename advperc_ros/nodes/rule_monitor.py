"""Node `rule_monitor`: every rule of the rulebook on the true agents and the ego, per frame.

It pairs /ground_truth/objects and /ego/odometry by stamp and answers each pair, frame k, first
with /rules/diagnostics (stamped, with the minimum and every agent's signed distance; see
`ros.lockstep`), which the player waits for, then with every registered rule's value at frame k on
its own topic (`topics.RULE_TOPICS`: /rules/<name>, Float64, r < 0 a violation) that has a subscriber
(a rule's value on a prefix costs in proportion to the prefix, so a search's graph, where nobody
listens, pays for none; docs/graph.md has the cost). The values are the
rulebook's own classes (`core.rules`) evaluated on what the monitor has seen of the rollout so far,
frames 0..k (`RolloutSoFar`): a live monitor must be causal, so where a rule smooths over frames to
come (the motion rules' Savitzky-Golay filters) its value at frame k is the value on the drive
ending at k, and the report's (the whole drive, after the rollout) is the reference (docs/graph.md).
The road is the player's latched /map/lanes and /ego/route; rules that judge the drive against the
ground truth's rollout read it from the latched /attack/reference, which the graph backend
publishes once it has that rollout, and until then judge the drive against itself, as the report
judges the ground truth. Inputs left unpaired when a new rollout starts (`StampPairs`) are dropped.
"""

import math
import sys
from collections.abc import Mapping
from typing import Any

import numpy as np

from advperc_ros.configs import rulebook
from advperc_ros.core.boxes import BOX_FIELDS, BoxSequence
from advperc_ros.core.geometry import Polyline
from advperc_ros.core.rules.base import Rule, evaluate
from advperc_ros.core.rules.contact import CollisionRule
from advperc_ros.core.rules.inputs import RuleInputs
from advperc_ros.core.rules.registry import RULES
from advperc_ros.core.scenario import Lane
from advperc_ros.nodes.runtime import Logger, NodeSpec, ground_truth_objects, run_node
from advperc_ros.params import RULE_THRESHOLDS
from advperc_ros.ros import bag as bags
from advperc_ros.ros import cdr
from advperc_ros.ros import messages as msgs
from advperc_ros.ros.lockstep import ReferenceDrive, StampPairs, parse_reference, rule_diagnostics
from advperc_ros.ros.topics import (
    CONTROL_TYPE,
    GROUND_TRUTH,
    LANES,
    ODOMETRY,
    REFERENCE,
    ROUTE,
    RULE_DIAGNOSTICS,
    RULE_TOPICS,
    TOPIC_TYPES,
)
from advperc_ros.ros.transport import Transport

UNKNOWN_PERIOD = math.inf
"""The frame period before any rollout has shown two frames: no rule reads it on a one-frame drive."""


def monitored_rules(values: Mapping[str, Any]) -> dict[str, Rule]:
    """The rules the monitor publishes, every registered one with the params' thresholds (`rule.<rule>.<parameter>`,
    the same `Rulebook` the search and the report judge by): built here only."""
    book = rulebook(values)
    return {name: book.rule(name) for name in RULES}


class RolloutSoFar:
    """Frames 0..k of the rollout in progress as the monitor paired them: the ego's states, the true
    agents with one slot per agent id (as a scenario holds them, so rules that follow an agent over
    frames see the same agent), their signed distances. Arrays grow in place: a frame costs its own
    agents, not the frames before it."""

    def __init__(self) -> None:
        self.stamps: list[int] = []
        self._slots: dict[int, int] = {}
        self._ego = np.zeros((0, 4))
        self._boxes: dict[str, np.ndarray] = {}
        self._valid = np.zeros((0, 0), dtype=bool)
        self._distances = np.zeros((0, 0))
        self.clear()

    def clear(self) -> None:
        """Forget the rollout (a new one has started)."""
        self.stamps = []
        self._slots = {}
        self._allocate(16, 8)

    def _allocate(self, frames: int, slots: int) -> None:
        """Room for `frames` x `slots` (no less than there is), what is held copied in; free slots as
        BoxSequence.empty leaves them."""
        room = BoxSequence.empty(frames, slots)
        boxes = {name: getattr(room, name) for name in ("ids", *BOX_FIELDS)}
        valid, distances, ego = room.valid, np.full((frames, slots), np.inf), np.zeros((frames, 4))
        held, width = self._valid.shape
        if self.stamps:
            for name, values in self._boxes.items():
                boxes[name][:held, :width] = values
            valid[:held, :width] = self._valid
            distances[:held, :width] = self._distances
            ego[:held] = self._ego
        self._boxes, self._valid, self._distances, self._ego = boxes, valid, distances, ego

    def add(self, stamp: int, truth: dict[str, np.ndarray], ego: np.ndarray, distances: np.ndarray) -> None:
        """Frame k: its stamp, the true agents (`cdr.decode_objects`' dict), the ego (x, y, yaw, v) and its
        signed distance to each of those agents, in their order."""
        for agent in truth["ids"].tolist():
            self._slots.setdefault(agent, len(self._slots))
        k = len(self.stamps)
        frames, slots = self._valid.shape
        if k >= frames or len(self._slots) > slots:
            self._allocate(2 * frames if k >= frames else frames, max(slots, 2 * len(self._slots)))
        columns = np.array([self._slots[agent] for agent in truth["ids"].tolist()], dtype=int)
        self._valid[k, columns] = True
        for name, values in self._boxes.items():
            values[k, columns] = truth.get(name, np.nan if name == "score" else 0.0)
        self._distances[k, columns] = distances
        self._ego[k] = ego
        self.stamps.append(stamp)

    @property
    def num_frames(self) -> int:
        return len(self.stamps)

    def agents(self) -> BoxSequence:
        """The true agents at frames 0..k, one slot per agent id seen so far."""
        k, width = len(self.stamps), len(self._slots)
        boxes = {name: values[:k, :width] for name, values in self._boxes.items()}
        return BoxSequence(valid=self._valid[:k, :width], **boxes)

    def recording(self, recorded: BoxSequence) -> BoxSequence:
        """The recording `recorded` (a scenario's agents) at frames 0..k in this rollout's slots, matched by id:
        what reactive agents left, for the rules that judge their reaction (forced_braking, at-fault contacts)."""
        first = recorded.valid.argmax(axis=0)
        column = {int(recorded.ids[k, j]): j for j, k in enumerate(first.tolist())}
        return recorded.select(slice(0, len(self.stamps))).select_slots(
            np.array([column[agent] for agent in self._slots], dtype=int))

    def inputs(self, dt: float, lanes: tuple[Lane, ...], route: Polyline, ego_size: tuple[float, float],
               recorded: BoxSequence | None = None) -> RuleInputs:
        """The rules' view of frames 0..k: every plan so far valid (the player went on from each, and
        frame k's own comes after this answer), the planner's fallback unknown (the graph carries no
        planner statistics); under reactive traffic with the recording the agents left (`recorded`)."""
        k = len(self.stamps)
        return RuleInputs(ego=self._ego[:k], dt=dt, agents=self.agents(), distances=self._distances[:k, :len(self._slots)],
                          lanes=lanes, route=route, ego_length=ego_size[0], ego_width=ego_size[1],
                          plan_valid=np.ones(k, dtype=bool),
                          recorded=None if recorded is None else self.recording(recorded))


def reference_inputs(reference: ReferenceDrive, lanes: tuple[Lane, ...], route: Polyline,
                     ego_size: tuple[float, float]) -> RuleInputs:
    """The ground truth's rollout as the rules that compare with it read it: its ego states on the road
    (`needs_reference` rules read nothing else of it: phantom braking its speeds, progress its positions)."""
    frames = reference.ego.shape[0]
    return RuleInputs(ego=reference.ego, dt=reference.dt, agents=BoxSequence.empty(frames, 0),
                      distances=np.zeros((frames, 0)), lanes=lanes, route=route, ego_length=ego_size[0],
                      ego_width=ego_size[1], plan_valid=np.ones(frames, dtype=bool))


def values_at_last_frame(rules: dict[str, Rule], inputs: RuleInputs, reference: RuleInputs | None) -> dict[str, float]:
    """Each rule's value at the last frame of `inputs`, against `reference` (None: the drive itself, as
    the report judges the ground truth's rollout against itself)."""
    against = inputs if reference is None else reference
    return {name: float(evaluate(rule, inputs, against).per_frame[-1]) for name, rule in rules.items()}


class RuleMonitor:
    """The rule monitor's logic without its process, built on any Transport: the same rules as the
    embedded rollout's and the report's (`core.rules`), judged on the true agents, never on what the
    planner saw."""

    def __init__(self, transport: Transport, ego_length: float, ego_width: float, logger: Logger,
                 rules: dict[str, Rule], recorded: BoxSequence | None = None) -> None:
        """`recorded`: under reactive traffic, the scenario's recording, which the player's agents left."""
        self._ego_size = (ego_length, ego_width)
        self._recorded = recorded
        self._log = logger
        self._rules = rules
        self._pairs = StampPairs(self._answer)
        self.so_far = RolloutSoFar()
        self._period: float | None = None  # s between frames: every rollout replays the same stamps
        self._lanes: tuple[Lane, ...] = ()
        self._route: Polyline | None = None
        self._reference: ReferenceDrive | None = None
        self._road_missing_said = False
        self._diagnostics = transport.publisher(RULE_DIAGNOSTICS, TOPIC_TYPES[RULE_DIAGNOSTICS])
        self._values = {name: transport.publisher(RULE_TOPICS[name], TOPIC_TYPES[RULE_TOPICS[name]]) for name in rules}
        transport.subscriber(GROUND_TRUTH, TOPIC_TYPES[GROUND_TRUTH], callback=self.on_ground_truth, raw=True)
        transport.subscriber(ODOMETRY, TOPIC_TYPES[ODOMETRY], callback=self.on_odometry, raw=True)
        transport.subscriber(LANES, TOPIC_TYPES[LANES], latched=True, callback=self.on_lanes, raw=True)
        transport.subscriber(ROUTE, TOPIC_TYPES[ROUTE], latched=True, callback=self.on_route, raw=True)
        transport.subscriber(REFERENCE, CONTROL_TYPE, latched=True, callback=self.on_reference)

    def on_ground_truth(self, data: bytes) -> None:
        stamp, truth = ground_truth_objects(data)
        if stamp is None:
            self._log.error(f"{GROUND_TRUTH}: a MarkerArray without markers has no stamp; dropped")
            return
        self._pairs.put(0, stamp, truth)

    def on_odometry(self, data: bytes) -> None:
        self._pairs.put(1, *msgs.ego_from_cdr(data, ODOMETRY))

    def on_lanes(self, data: bytes) -> None:
        self._lanes = bags.lanes_of([(0, data)], LANES)

    def on_route(self, data: bytes) -> None:
        self._route = bags.route_of([(0, data)], ROUTE)

    def on_reference(self, msg: Any) -> None:
        self._reference = parse_reference(msg)

    def _answer(self, stamp: int, truth: dict, ego: Any) -> None:
        first, _ = self._pairs.clock.answer(stamp)
        rule = CollisionRule(BoxSequence.stack([truth]), *self._ego_size)
        distances = rule.distances(np.array([[ego.x, ego.y, ego.yaw]]), [0])[0]
        self._diagnostics.publish(rule_diagnostics(stamp, truth["ids"], distances))  # the player waits for it alone
        if first:
            self.so_far.clear()
        self.so_far.add(stamp, truth, np.array([ego.x, ego.y, ego.yaw, ego.v]), distances)
        if self.so_far.num_frames == 2:
            self._period = float(self.so_far.stamps[1] - self.so_far.stamps[0]) * 1e-9  # as Scenario.dt
        watched = [name for name, publisher in self._values.items() if publisher.matched_count() > 0]
        if not watched:  # nobody listens (a search's graph): the rules cost nothing but the frame's append
            return
        if self._route is None:
            if not self._road_missing_said:
                self._log.warning(f"no {ROUTE} yet: the rules are not published until the player's route is in")
                self._road_missing_said = True
            return
        for name, value in self.values(watched).items():
            self._values[name].publish(cdr.encode_float64(value))

    def values(self, names: list[str]) -> dict[str, float]:
        """The value of each of the monitored rules `names` at the last frame seen (the road must be in)."""
        assert self._route is not None
        period = self._period or (self._reference.dt if self._reference is not None else UNKNOWN_PERIOD)
        inputs = self.so_far.inputs(period, self._lanes, self._route, self._ego_size, self._recorded)
        reference = (None if self._reference is None
                     else reference_inputs(self._reference, self._lanes, self._route, self._ego_size))
        return values_at_last_frame({name: self._rules[name] for name in names}, inputs, reference)


def _build(transport: Transport, values: dict[str, Any], planner_params: dict[str, Any], logger: Logger) -> RuleMonitor:
    recorded = bags.read_scenario(values["bag"]).agents if values["traffic.reactive"] else None
    return RuleMonitor(transport, values["ego.length"], values["ego.width"], logger, monitored_rules(values), recorded)


SPEC = NodeSpec("rule_monitor", ("bag", "ego.length", "ego.width", "traffic.reactive", *RULE_THRESHOLDS), _build)


def main(args: list[str] | None = None) -> int:
    return run_node(SPEC, args)


if __name__ == "__main__":
    sys.exit(main())
