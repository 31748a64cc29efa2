"""A ROS 2 compatible topic transport on Cyclone DDS, without rclpy.

It follows what rmw_cyclonedds puts on the wire, so these processes and real ROS 2 nodes
(same domain id, discovery able to reach each other) see each other's topics:

- topic `/a/b` is the DDS topic `rt/a/b`; type `pkg/msg/T` is `pkg::msg::dds_::T_` (dds_types);
- payloads are plain CDR (XCDR1), what ROS 2 sends. Writers offer only that (Cyclone's default
  here too) and readers accept only that: by default they would also accept XCDR2, which rosbags
  cannot decode, so a writer offering XCDR2 must fail to match visibly rather than deliver
  undecodable samples;
- QoS is the contract's (`topics.depth`): reliable, keep-last 1000, volatile; latched topics are transient-local
  keep-last 1, which is what ROS 2 calls latching.

Messages go in as rosbags message objects (`advperc_ros.ros.messages`) or as their CDR payload
(bytes, `advperc_ros.ros.cdr`), and come out as rosbags objects or, from a `raw` subscription, as
the CDR payload. The payload is handed to Cyclone as bytes, and received bytes are decoded by
rosbags (or not at all when raw), skipping Cyclone's much slower Python (de)serialiser. That uses
the two functions DataWriter.write and DataReader.take themselves call
(`cyclonedds._clayer.ddspy_write` and `ddspy_take`); should a cyclonedds release drop them, the
public API is used instead (through `dds_types.to_idl` / `idl_to_cdr`), slower but identical
on the wire.

Discovery is loopback-only by default (`LOCALHOST_CONFIG`, like ROS's
`ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`). Volatile topics only reach readers that are already
matched: call `Publication.wait_for_subscribers` before the first message that must arrive.
Builtin-topic readers are never created (they crash cyclonedds 11.0.1); matching is observed
through the writer's and reader's matched status instead.

A transport is meant for one thread. Callbacks run on the thread calling `spin_once`, never on
Cyclone's receive thread, so a callback may publish without risking a deadlock on flow control.
"""

import os
import time
from collections.abc import Callable
from types import TracebackType
from typing import Any

from cyclonedds.core import DDSException, InstanceState, ReadCondition, SampleState, ViewState, WaitSet
from cyclonedds.domain import Domain, DomainParticipant
from cyclonedds.pub import DataWriter, Publisher
from cyclonedds.qos import Policy, Qos
from cyclonedds.sub import DataReader, Subscriber
from cyclonedds.topic import Topic
from cyclonedds.util import duration

from advperc_ros.exceptions import DdsError
from advperc_ros.ros import dds_types
from advperc_ros.ros.cdr import payload
from advperc_ros.ros.topics import depth, with_prompt_heartbeats

try:  # the fast path: CDR bytes straight to Cyclone (see the module docstring)
    from cyclonedds._clayer import ddspy_take as _ddspy_take
    from cyclonedds._clayer import ddspy_write as _ddspy_write
except ImportError:  # pragma: no cover - depends on the installed cyclonedds
    _ddspy_take = None
    _ddspy_write = None

LOCALHOST_CONFIG = (
    "<CycloneDDS><Domain><General><Interfaces><NetworkInterface name=\"lo\"/></Interfaces>"
    "<AllowMulticast>false</AllowMulticast></General><Discovery><ParticipantIndex>auto</ParticipantIndex>"
    "<MaxAutoParticipantIndex>{max_index}</MaxAutoParticipantIndex>"
    "<Peers><Peer address=\"127.0.0.1\"/></Peers></Discovery></Domain></CycloneDDS>"
)
"""Loopback only, unicast discovery. Each process takes a participant index (a port pair) and
probes the indices 0..max_index on 127.0.0.1, so at most max_index + 1 processes can join a
domain on one host; Cyclone's default of 9 is too tight for six nodes, an orchestrator and tools."""
MAX_PROCESSES = 32

_ANY_STATE = SampleState.Any | ViewState.Any | InstanceState.Any
_TAKE_BATCH = 256
_POLL_S = 0.002

_DOMAINS: dict[int, tuple[Domain, bool, bool]] = {}  # id -> (domain, localhost_only, prompt_heartbeats)
"""Cyclone domains configured by this process: one per id, for the process's lifetime."""


def dds_topic_name(topic: str) -> str:
    """ROS topic name -> DDS topic name (`/a/b` -> `rt/a/b`)."""
    return "rt/" + topic.lstrip("/")


def _qos(latched: bool, msgtype: str, reader: bool = False) -> Qos:
    """The contract's QoS, plus the USER_DATA `typehash=RIHS01_...;` that ROS 2 Jazzy endpoints
    carry (informational: `ros2 topic info -v` shows it; matching does not depend on it)."""
    return Qos(
        Policy.Reliability.Reliable(max_blocking_time=duration(milliseconds=100)),
        Policy.Durability.TransientLocal if latched else Policy.Durability.Volatile,
        Policy.History.KeepLast(depth(latched, reader)),
        Policy.DataRepresentation(use_cdrv0_representation=True),
        Policy.Userdata(data=f"typehash={dds_types.TYPESTORE.hash_rihs01(msgtype)};".encode()),
    )


def _domain(domain_id: int, localhost_only: bool, prompt_heartbeats: bool) -> None:
    """Configure the Cyclone domain once per process; a second, different request is an error."""
    if domain_id in _DOMAINS:
        if _DOMAINS[domain_id][1:] != (localhost_only, prompt_heartbeats):
            raise DdsError(f"domain {domain_id}: already set up with localhost_only={_DOMAINS[domain_id][1]}, "
                           f"prompt_heartbeats={_DOMAINS[domain_id][2]} in this process")
        return
    # not loopback only: CYCLONEDDS_URI or Cyclone's defaults, as the user widened discovery
    config = LOCALHOST_CONFIG.format(max_index=MAX_PROCESSES - 1) if localhost_only else os.environ.get("CYCLONEDDS_URI")
    if prompt_heartbeats:
        config = with_prompt_heartbeats(config)
    try:
        domain = Domain(domain_id, config)
    except DDSException as exc:
        hint = f" (more than {MAX_PROCESSES} processes on this domain, or its UDP ports taken?)" if localhost_only else ""
        raise DdsError(f"domain {domain_id}: Cyclone DDS could not start it{hint}: {exc}") from exc
    _DOMAINS[domain_id] = (domain, localhost_only, prompt_heartbeats)


def _delete(entity: Any) -> None:
    """Delete a Cyclone entity now (cyclonedds only deletes in __del__, at garbage collection)."""
    entity.__del__()
    if isinstance(entity, WaitSet):
        entity.attached = []  # already detached; a second __del__ must not detach again


def _pad(payload: bytes) -> bytes:
    """Pad a CDR payload to 4 bytes and record the padding in the encapsulation options, as
    XTypes 7.6.3.1.2 says and rmw_cyclonedds does (readers then know the true length)."""
    pad = -len(payload) % 4
    if not pad:
        return payload
    return payload[:3] + bytes([payload[3] | pad]) + payload[4:] + b"\0" * pad


class Publication:
    """A writer of one ROS topic; made by `DdsTransport.publisher`."""

    def __init__(self, writer: DataWriter, topic: str, msgtype: str) -> None:
        self.topic = topic
        self.msgtype = msgtype
        self._writer = writer

    def publish(self, msg: object) -> None:
        """Send a rosbags message of this topic's type, or its CDR payload (bytes) as it is."""
        data = payload(msg, self.msgtype)
        if _ddspy_write is not None:
            ret = _ddspy_write(self._writer._ref, _pad(data))
            if ret < 0:
                raise DdsError(f"{self.topic}: write failed with DDS return code {ret}")
        else:  # public API fallback, slower
            self._writer.write(dds_types.to_idl(data, self.msgtype))

    def matched_count(self) -> int:
        """Readers currently matched (local and remote)."""
        return int(self._writer.get_publication_matched_status().current_count)

    def wait_for_subscribers(self, count: int = 1, timeout: float = 5.0) -> bool:
        """Block until at least `count` readers are matched; False on timeout. Needed before
        the first message a late-joining reader must get on a volatile topic."""
        return _poll(lambda: self.matched_count() >= count, timeout)

    def wait_for_acks(self, timeout: float = 5.0) -> bool:
        """Block until every matched reliable reader acknowledged everything; False on timeout."""
        return bool(self._writer.wait_for_acks(duration(seconds=timeout)))


class Subscription:
    """A reader of one ROS topic; made by `DdsTransport.subscriber`."""

    def __init__(self, participant: DomainParticipant, reader: DataReader, topic: str, msgtype: str,
                 callback: Callable[[Any], None] | None, raw: bool) -> None:
        self.topic = topic
        self.msgtype = msgtype
        self.callback = callback
        self.raw = raw
        self._reader = reader
        self.condition = ReadCondition(reader, _ANY_STATE)
        self._waitset = WaitSet(participant)
        self._waitset.attach(self.condition)

    def take(self) -> list[Any]:
        """All messages received so far and not yet taken, oldest first (non-blocking): rosbags
        messages, or CDR payloads (bytes, maybe padded to 4 bytes) if the subscription is raw."""
        out: list[bytes] = []
        while True:
            if _ddspy_take is not None:
                samples = _ddspy_take(self._reader._ref, _ANY_STATE, _TAKE_BATCH)
                if isinstance(samples, int):
                    raise DdsError(f"{self.topic}: take failed with DDS return code {samples}")
                # invalid samples only announce a writer's disappearance
                out.extend(data for data, info in samples if info.valid_data)
            else:  # public API fallback, slower
                samples = self._reader.take(_TAKE_BATCH)
                out.extend(dds_types.idl_to_cdr(s) for s in samples if s.sample_info.valid_data)
            if len(samples) < _TAKE_BATCH:
                return out if self.raw else [dds_types.from_cdr(data, self.msgtype) for data in out]

    def wait(self, timeout: float) -> list[Any]:
        """Like `take`, but first block until something arrives or `timeout` seconds pass
        (then the list is empty)."""
        deadline = time.monotonic() + timeout
        while True:
            messages = self.take()
            remaining = deadline - time.monotonic()
            if messages or remaining <= 0:
                return messages
            self._waitset.wait(duration(seconds=remaining))

    def matched_count(self) -> int:
        """Writers currently matched (local and remote)."""
        return int(self._reader.get_subscription_matched_status().current_count)


def _poll(done: Callable[[], bool], timeout: float) -> bool:
    deadline = time.monotonic() + timeout
    while not done():
        if time.monotonic() >= deadline:
            return False
        time.sleep(_POLL_S)
    return True


class DdsTransport:
    """One DDS participant on `domain_id`, with publishers and subscribers of ROS topics.

    `localhost_only` (the default) keeps all DDS traffic on 127.0.0.1 whatever CYCLONEDDS_URI
    says; with False, Cyclone's own configuration (CYCLONEDDS_URI or its defaults) applies.
    A process can hold several transports on one domain, all with the same `localhost_only`.
    `partition`: a DDS partition for every reader and writer, so that graphs in other partitions
    on the same domain are invisible to this one ("" is the default partition, the one ROS 2 uses).
    `prompt_heartbeats`: the writers ask for acknowledgements every 1 ms (`topics.PROMPT_HEARTBEATS`),
    for a node that waits for them (the clock drive's player and tracker).
    """

    def __init__(self, domain_id: int, localhost_only: bool = True, partition: str = "",
                 prompt_heartbeats: bool = False) -> None:
        if not 0 <= domain_id <= 232:
            raise DdsError(f"domain id {domain_id}: must be within 0..232 (RTPS port mapping)")
        _domain(domain_id, localhost_only, prompt_heartbeats)
        self.domain_id = domain_id
        self._participant: DomainParticipant | None = DomainParticipant(domain_id)
        scope = Qos(Policy.Partition(partitions=[partition]))
        self._publisher = Publisher(self._participant, qos=scope)
        self._subscriber = Subscriber(self._participant, qos=scope)
        self._topics: dict[str, tuple[Topic, str]] = {}
        self._publications: list[Publication] = []
        self._subscriptions: list[Subscription] = []
        self._spin_waitset: WaitSet | None = None
        self._spinning: list[Subscription] = []  # the subscriptions with a callback

    @property
    def participant(self) -> DomainParticipant:
        if self._participant is None:
            raise DdsError("transport is closed")
        return self._participant

    def _topic(self, topic: str, msgtype: str) -> Topic:
        if not topic.startswith("/"):
            raise DdsError(f"topic {topic!r}: must be an absolute ROS name (leading '/')")
        known = self._topics.get(topic)
        if known is not None:
            if known[1] != msgtype:
                raise DdsError(f"topic {topic}: already used with type {known[1]}, not {msgtype}")
            return known[0]
        dds_topic = Topic(self.participant, dds_topic_name(topic), dds_types.idl_type(msgtype))
        self._topics[topic] = (dds_topic, msgtype)
        return dds_topic

    def publisher(self, topic: str, msgtype: str, latched: bool = False) -> Publication:
        """A writer of `topic` (ROS name) carrying `msgtype` (`pkg/msg/Type`)."""
        writer = DataWriter(self._publisher, self._topic(topic, msgtype), _qos(latched, msgtype))
        publication = Publication(writer, topic, msgtype)
        self._publications.append(publication)
        return publication

    def subscriber(self, topic: str, msgtype: str, latched: bool = False,
                   callback: Callable[[Any], None] | None = None, raw: bool = False,
                   wake: bool = True) -> Subscription:
        """A reader of `topic`. With a callback, messages are delivered by `spin_once`;
        without, the caller takes them with `take` / `wait`. A latched reader also gets the
        last message published before it joined. `raw`: deliver CDR payloads, not messages.
        `wake=False`: a message does not end `spin_once`'s wait; it is delivered with the next
        one that ends (another subscription's message, or the timeout)."""
        reader = DataReader(self._subscriber, self._topic(topic, msgtype), _qos(latched, msgtype, reader=True))
        subscription = Subscription(self.participant, reader, topic, msgtype, callback, raw)
        self._subscriptions.append(subscription)
        if callback is not None:
            if self._spin_waitset is None:
                self._spin_waitset = WaitSet(self.participant)
            if wake:
                self._spin_waitset.attach(subscription.condition)
            self._spinning.append(subscription)
        return subscription

    def spin_once(self, timeout: float) -> int:
        """Wait up to `timeout` seconds for messages on subscriptions with a callback and call
        the callbacks, in this thread; returns the number of messages delivered. A callback's
        exception propagates (after which the rest of that subscription's batch is dropped).
        The waitset stays triggered while a reader holds samples, so it is waited on first and
        each reader taken from once per wake-up (every take is a call into Cyclone); readers
        that do not wake it are taken from too, also on a timeout."""
        if not self._spinning or self._spin_waitset is None:
            time.sleep(max(timeout, 0.0))
            return 0
        deadline = time.monotonic() + timeout
        while True:
            remaining = max(deadline - time.monotonic(), 0.0)
            woke = self._spin_waitset.wait(duration(seconds=remaining))
            delivered = 0
            for subscription in self._spinning:
                for msg in subscription.take():
                    subscription.callback(msg)  # type: ignore[misc]
                    delivered += 1
            if delivered or not woke or not remaining:  # else only writer-gone notices were taken
                return delivered

    def publishers_of(self, topic: str) -> None:
        """Node names are a ROS layer above DDS (rmw's ros_discovery_info), not read here."""
        return None

    def node_names(self) -> None:
        """As `publishers_of`: no node names over bare DDS."""
        return None

    def publisher_count(self, topic: str) -> int | None:
        """The writers matched by this transport's readers of `topic` (DDS discovery); None without one."""
        readers = [subscription for subscription in self._subscriptions if subscription.topic == topic]
        return sum(subscription.matched_count() for subscription in readers) if readers else None

    def best_effort_publishers(self, topic: str) -> None:
        """A remote writer's QoS is in the builtin publication topic, whose readers crash cyclonedds 11.0.1."""
        return None

    def close(self) -> None:
        """Delete the participant and everything in it now (idempotent)."""
        if self._participant is None:
            return
        if self._spin_waitset is not None:
            _delete(self._spin_waitset)
        for subscription in self._subscriptions:
            _delete(subscription._waitset)
            _delete(subscription.condition)
            _delete(subscription._reader)
        for publication in self._publications:
            _delete(publication._writer)
        for dds_topic, _ in self._topics.values():
            _delete(dds_topic)
        _delete(self._publisher)
        _delete(self._subscriber)
        _delete(self._participant)
        self._participant = None
        self._spin_waitset = None
        self._spinning.clear()
        self._subscriptions.clear()
        self._publications.clear()
        self._topics.clear()

    def __enter__(self) -> "DdsTransport":
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 traceback: TracebackType | None) -> None:
        self.close()
