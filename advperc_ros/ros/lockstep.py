"""Messages of the lockstep protocol beyond the data topics: rollout control and rule values.

Control topics carry std_msgs/String holding JSON (so any ROS 2 tool can read them; floats are
written with `repr` by the json module and so round-trip exactly):

| topic | QoS | from -> to | JSON |
|---|---|---|---|
| /attack/errors | latched | orchestrator -> injector | {"rollout", "agent_ids", "stamps_ns", "dx", "dy", "dyaw", "fn", "ahead", "confirmed"}, and the arrays of each extended error kind on (`core.perception_errors.KINDS`) |
| /attack/ready | volatile | injector -> player | {"rollout", "ahead", "confirmed"}: the injector holds that rollout's errors |
| /attack/delivered | volatile | tracker -> player | {"topic", "stamp_ns"}: (drive: clock) every reader of the tracks stamped stamp_ns holds them |
| /attack/done | volatile | player -> orchestrator | {"rollout", "frames", "status": "ok" or "inconclusive", "reason", "timeout", "gone"} |
| /attack/nodes | latched | every graph node -> orchestrator | {"node", "pid"}: the node is up, its topics created |
| /attack/reference | latched | orchestrator -> rule monitor | {"ego", "dt"}: the ground truth's rollout (ego rows x, y, yaw, v; frame period s) |

`ahead` (optional, false when absent) lets the player publish each frame's ground truth one frame
ahead of the ego, so that the injector and the tracker work on frame k+1 while the planner plans
frame k (docs/graph.md, "Perception one frame ahead"); the orchestrator sets it only when the
planner and the tracker are ours and the planner is driven by messages.

`confirmed` (optional, false when absent) tells the player, under the clock drive, that the tracks
come from our tracker, which confirms on /attack/delivered that every reader holds a frame's tracks
(each reader acknowledged them, `Publisher.wait_for_acks`): the player advances /clock to t_k only
then, so that a timer the clock fires finds frame k's tracks in its node, however loaded the
machine. A team's tracker confirms nothing; the player then goes by the tracks' arrival at itself.

`timeout` in /attack/done is true when the rollout is inconclusive because the graph failed to
answer (a node died or went silent), as opposed to the planner's own failure; the orchestrator
then restarts the nodes it owns. `gone` (optional, "" when absent) says, with a timeout, that no
node publishes a topic the frame waited on any more (the player's readers match no publisher): a
node gone for good, which ends the search.

/rules/diagnostics carries the rule value of frame k stamped t_k: one DiagnosticStatus named
`collision` whose KeyValues are `min_signed_distance` and `agent <id>` per agent present, values
written with `repr` (exact round trip; `inf` where nothing is present).
"""  # noqa: E501 -- a Markdown table keeps each row on one line

import json
import math
import re
from collections.abc import Callable
from dataclasses import dataclass
from enum import Enum
from typing import Any

import numpy as np

from advperc_ros.core.perception_errors import PerceptionErrors, registry
from advperc_ros.core.planners.base import Trajectory
from advperc_ros.exceptions import MessageError
from advperc_ros.ros import cdr
from advperc_ros.ros import messages as msgs
from advperc_ros.ros.topics import DELIVERED, DONE, ERRORS, PRESENCE, READY, REFERENCE, RULE_DIAGNOSTICS

RULE_STATUS = "collision"
MIN_KEY = "min_signed_distance"
AGENT_KEY = "agent "


class Status(str, Enum):
    """A rollout's verdict in /attack/done: it ran to its end (ok), or has none (inconclusive)."""

    OK = "ok"
    INCONCLUSIVE = "inconclusive"

    def __str__(self) -> str:
        return self.value



@dataclass(frozen=True)
class RolloutErrors:
    """The error tensor of one rollout, with what places it (agent id per slot, stamp per frame) and
    whether the player may run the ground truth one frame ahead of the ego (`ahead`)."""

    rollout: int
    errors: PerceptionErrors
    agent_ids: np.ndarray  # (N,) int64
    stamps_ns: np.ndarray  # (T,) int64
    ahead: bool = False
    confirmed: bool = False  # (drive: clock) our tracker confirms each frame's delivery on /attack/delivered


@dataclass(frozen=True)
class RolloutReady:
    """The injector holds rollout `rollout`'s errors; `ahead` and `confirmed` are the orchestrator's
    word, passed on."""

    rollout: int
    ahead: bool
    confirmed: bool = False


@dataclass(frozen=True)
class RolloutDone:
    """The player's /attack/done: how many frames ran and whether the rollout has a verdict; a
    `timeout` tells a graph that failed to answer from a planner that failed, since only the first
    restarts the nodes."""

    rollout: int
    frames: int
    status: Status
    reason: str
    timeout: bool
    gone: str = ""  # (a timeout) a node the graph needs is gone for good: no publisher of its topic is left


def errors_message(item: RolloutErrors):
    e = item.errors
    return msgs.string(json.dumps({
        "rollout": item.rollout,
        "agent_ids": item.agent_ids.tolist(),
        "stamps_ns": item.stamps_ns.tolist(),
        **{name: array.tolist() for name, array in e.arrays().items()},
        "ahead": item.ahead,
        "confirmed": item.confirmed,
    }))


def _json_object(msg, topic: str) -> dict:
    """The JSON object a control message carries. Nodes of other teams publish on these topics
    too: anything else is a MessageError naming the topic, not a KeyError deep in a callback."""
    try:
        data = json.loads(msg.data)
    except (TypeError, ValueError, RecursionError) as exc:  # RecursionError: arrays nested too deep
        raise MessageError(f"{topic}: field 'data' is not JSON ({exc})") from None
    if not isinstance(data, dict):
        raise MessageError(f"{topic}: field 'data' is not a JSON object")
    return data


def _field(data: dict, topic: str, name: str, kind: type, allowed: tuple = ()):
    """data[name], a JSON value of type `kind` (an int is not a bool), one of `allowed` if given."""
    value = data.get(name)
    if not isinstance(value, kind) or (kind is int and isinstance(value, bool)) or (allowed and value not in allowed):
        wanted = " or ".join(map(repr, allowed)) if allowed else kind.__name__
        shown = repr(value) if isinstance(value, (str, int, float)) and len(repr(value)) <= 40 else type(value).__name__
        raise MessageError(f"{topic}: field '{name}' must be {wanted}, not {shown}")
    return value


_ELEMENTS = {"f": ("fi", "finite numbers"), "i": ("i", "integers"), "b": ("b", "booleans")}
_ELEMENT_OF = {np.float64: "f", np.int64: "i", np.bool_: "b"}  # the JSON element of an error array's dtype


def _array(data: dict, topic: str, name: str, shape: tuple[int, ...] | None, kind: str) -> np.ndarray:
    """data[name] as an array of `shape` (None: any length, 1-D) of JSON finite numbers ('f'),
    integers ('i') or booleans ('b'); no conversion between them (`"1"` or `true` is no number)."""
    kinds, what = _ELEMENTS[kind]
    try:
        value = np.array(data.get(name))
    except ValueError:  # ragged lists
        value = np.array(None)
    empty = value.size == 0 and (shape is None or 0 in shape)
    fits = value.ndim == 1 if shape is None else value.shape == shape
    if not (empty or (fits and value.dtype.kind in kinds and (kind != "f" or np.isfinite(value).all()))):
        size = "1-D" if shape is None else "x".join(map(str, shape))
        raise MessageError(f"{topic}: field '{name}' must be a {size} array of {what}")
    return value.reshape(shape if shape is not None else -1)


def parse_errors(msg) -> RolloutErrors:
    data = _json_object(msg, ERRORS)
    stamps = _array(data, ERRORS, "stamps_ns", None, "i").astype(np.int64)
    agent_ids = _array(data, ERRORS, "agent_ids", None, "i").astype(np.int64)
    shape = (len(stamps), len(agent_ids))
    specs = registry.array_specs()
    ghosts = data.get(next((name for name, spec in specs.items() if spec.per_ghost), ""))
    ghost_shape = (len(stamps), len(ghosts[0]) if isinstance(ghosts, list) and ghosts and isinstance(ghosts[0], list) else 0)
    arrays = {}
    for kind in registry.KINDS:
        for spec in kind.arrays if kind.paper or any(name in data for name in kind.array_names) else ():
            arrays[spec.name] = _array(data, ERRORS, spec.name, ghost_shape if spec.per_ghost else shape,
                                       _ELEMENT_OF[spec.dtype])
    try:
        errors = PerceptionErrors.from_arrays(arrays)
    except ValueError as exc:
        raise MessageError(f"{ERRORS}: {exc}") from None
    return RolloutErrors(_field(data, ERRORS, "rollout", int), errors, agent_ids, stamps, _flag(data, ERRORS, "ahead"),
                         _flag(data, ERRORS, "confirmed"))


def _flag(data: dict, topic: str, name: str) -> bool:
    """An optional flag of a control message: false when absent (a sender that predates it)."""
    return name in data and _field(data, topic, name, bool)


def ready_message(ready: RolloutReady):
    return msgs.string(json.dumps({"rollout": ready.rollout, "ahead": ready.ahead, "confirmed": ready.confirmed}))


def parse_ready(msg) -> RolloutReady:
    data = _json_object(msg, READY)
    return RolloutReady(_field(data, READY, "rollout", int), _flag(data, READY, "ahead"), _flag(data, READY, "confirmed"))


@dataclass(frozen=True)
class Delivered:
    """(drive: clock) Every reader of `topic` holds its message stamped `stamp_ns`: the tracker's word
    to the player, which may then advance /clock to that stamp."""

    topic: str
    stamp_ns: int


def delivered_message(delivered: Delivered):
    return msgs.string(json.dumps({"topic": delivered.topic, "stamp_ns": delivered.stamp_ns}))


def parse_delivered(msg) -> Delivered:
    data = _json_object(msg, DELIVERED)
    return Delivered(_field(data, DELIVERED, "topic", str), _field(data, DELIVERED, "stamp_ns", int))


@dataclass(frozen=True)
class ReferenceDrive:
    """The ground truth's rollout of the scenario (the stack on perfect perception) as the rule monitor
    needs it: the rules that judge a drive against it read its ego states and frame period only."""

    ego: np.ndarray  # (K, 4) x, y, yaw, v of the ego's box centre at frames 0..K-1
    dt: float  # s between frames


def reference_message(reference: ReferenceDrive):
    return msgs.string(json.dumps({"ego": reference.ego.tolist(), "dt": reference.dt}))


def parse_reference(msg) -> ReferenceDrive:
    data = _json_object(msg, REFERENCE)
    rows = data.get("ego")
    if not (isinstance(rows, list) and rows):
        raise MessageError(f"{REFERENCE}: field 'ego' must be a non-empty Kx4 array of finite numbers")
    ego = _array(data, REFERENCE, "ego", (len(rows), 4), "f")
    dt = _field(data, REFERENCE, "dt", float)
    if not (math.isfinite(dt) and dt > 0.0):
        raise MessageError(f"{REFERENCE}: field 'dt' must be a positive number of seconds, not {dt!r}")
    return ReferenceDrive(ego.astype(float), dt)


def presence_message(node: str, pid: int):
    return msgs.string(json.dumps({"node": node, "pid": pid}))


def parse_presence(msg) -> tuple[str, int, str | None]:
    """(node name, process id, the version it announces or None). A team's node may announce itself
    too, with a `version` (a release, a commit): the report names it and config_hash covers it."""
    data = _json_object(msg, PRESENCE)
    version = _field(data, PRESENCE, "version", str) if "version" in data else None
    return _field(data, PRESENCE, "node", str), _field(data, PRESENCE, "pid", int), version


def done_message(done: RolloutDone):
    return msgs.string(json.dumps({"rollout": done.rollout, "frames": done.frames, "status": done.status.value,
                                   "reason": done.reason, "timeout": done.timeout, "gone": done.gone}))


def parse_done(msg) -> RolloutDone:
    data = _json_object(msg, DONE)
    return RolloutDone(_field(data, DONE, "rollout", int), _field(data, DONE, "frames", int),
                       Status(_field(data, DONE, "status", str, tuple(s.value for s in Status))),
                       _field(data, DONE, "reason", str), _field(data, DONE, "timeout", bool),
                       _field(data, DONE, "gone", str) if "gone" in data else "")


def rule_diagnostics(ns_time: int, agent_ids: np.ndarray, distances: np.ndarray) -> bytes:
    """The rule value of one frame, minimum and per-agent signed distances (m), as CDR."""
    minimum = float(distances.min(initial=np.inf))
    values = {MIN_KEY: repr(minimum)}
    values.update({f"{AGENT_KEY}{int(i)}": repr(float(d)) for i, d in zip(agent_ids, distances)})
    violated = minimum < 0.0
    return msgs.diagnostics_cdr(ns_time, RULE_STATUS, "violated" if violated else "ok", values, level=2 if violated else 0)


def parse_rule_diagnostics(data: bytes) -> tuple[int, float, dict[int, float]]:
    """(stamp ns, minimum, distance per agent id) of a /rules/diagnostics message's CDR; a
    MessageError naming the field if it has no `collision` status or a value is not a number."""
    stamp, statuses = cdr.decode_diagnostics(data, RULE_DIAGNOSTICS)
    status = next((s for s in statuses if s.name == RULE_STATUS), None)
    if status is None:
        raise MessageError(f"{RULE_DIAGNOSTICS}: field 'status' holds no status named '{RULE_STATUS}'")
    if MIN_KEY not in status.values:
        raise MessageError(f"{RULE_DIAGNOSTICS}: field '{MIN_KEY}' is missing")
    per_agent = {}
    for key, text in status.values.items():
        if key.startswith(AGENT_KEY):
            agent = key[len(AGENT_KEY):]
            if not re.fullmatch(r"-?[0-9]{1,19}", agent):  # an int64 as written; int() would also take " 3", "3_0"
                raise MessageError(f"{RULE_DIAGNOSTICS}: field {key!r} does not name an agent id")
            per_agent[int(agent)] = _distance(key, text)
    return stamp, _distance(MIN_KEY, status.values[MIN_KEY]), per_agent


def _distance(key: str, text: str) -> float:
    """A signed distance as `repr` wrote it: a number, inf where nothing is present, never nan."""
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if math.isnan(value):
        raise MessageError(f"{RULE_DIAGNOSTICS}: field {key!r} is not a distance: {text!r:.40}")
    return value


def plan_from_cdr(data: cdr.Cdr, first_stamp_ns: int, where: str) -> tuple[int, Trajectory]:
    """A nav_msgs/Path's CDR as (its stamp, the plan the embedded rollout follows: pose times in
    seconds since the scenario's first stamp, computed as `Scenario.times` computes frame times)."""
    stamp, poses, stamps = cdr.decode_path(data, where)
    return stamp, Trajectory(t=(stamps - np.int64(first_stamp_ns)) * 1e-9, x=poses[:, 0], y=poses[:, 1], yaw=poses[:, 2])


class RolloutClock:
    """Tells rollouts apart from stamps alone, so a node needs no control topic and an external
    planner can follow the same rule: an input stamped at or before the last answered stamp
    starts a new rollout (every rollout starts again at the scenario's first stamp, and the
    player never publishes frame k+1 before frame k is answered). Times are counted from the
    rollout's first stamp, exactly as `Scenario.times` counts them."""

    def __init__(self) -> None:
        self._origin = 0
        self._answered: int | None = None
        self._fresh = True

    def observe(self, stamp: int) -> bool:
        """Call on every input; True when it begins a new rollout (inputs still pending from
        the previous one must then be dropped)."""
        if self._answered is not None and stamp <= self._answered:
            self._answered = None
            self._fresh = True
            return True
        return False

    def answer(self, stamp: int) -> tuple[bool, float]:
        """Call when answering the input(s) stamped `stamp`: (first answer of a rollout, so reset
        the core object; seconds since the rollout's first stamp)."""
        first = self._fresh
        if first:
            self._origin = stamp
            self._fresh = False
        self._answered = stamp
        return first, (stamp - self._origin) * 1e-9


class RisingStamps:
    """One input stream's stamps, which rise within a rollout (each node publishes its frames in
    order, and every rollout starts again at the first stamp): a stamp at or below the stream's
    last one begins a new rollout on that stream, and what the stream left unpaired is stale.
    With perception one frame ahead, the previous rollout can leave one input stamped past its
    last frame, which can reach a node after the next rollout's first input from elsewhere; the
    stream's own restart is what tells it from the next rollout's input with that stamp."""

    def __init__(self) -> None:
        self._last: int | None = None

    def restarts(self, stamp: int) -> bool:
        """Call on every input of the stream; True when it begins a new rollout on the stream."""
        restarted = self._last is not None and stamp <= self._last
        self._last = stamp
        return restarted


class StampPairs:
    """Pairs two input streams (`put(0, ...)`, `put(1, ...)`) by stamp and calls `answer(stamp,
    first, second)` once both are in; what is still unpaired when a new rollout starts is dropped,
    and so is what one stream left unpaired when that stream starts again (`RisingStamps`)."""

    def __init__(self, answer: Callable[[int, Any, Any], None]) -> None:
        self.clock = RolloutClock()
        self._answer = answer
        self._pending: tuple[dict[int, Any], dict[int, Any]] = ({}, {})
        self._streams = (RisingStamps(), RisingStamps())

    def put(self, stream: int, stamp: int, value: Any) -> None:
        if self.clock.observe(stamp):
            for pending in self._pending:
                pending.clear()
        if self._streams[stream].restarts(stamp):
            self._pending[stream].clear()
        self._pending[stream][stamp] = value
        if all(stamp in pending for pending in self._pending):
            first, second = (pending.pop(stamp) for pending in self._pending)
            self._answer(stamp, first, second)
