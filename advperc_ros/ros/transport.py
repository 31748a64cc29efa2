"""The one small interface the graph nodes talk through, and its rclpy adapter.

Node logic (advperc_ros.nodes) and the graph backend (advperc_ros.backends.graph) only ever call
`publisher(topic, msgtype, latched).publish(msg)`, `subscriber(topic, msgtype, latched,
callback, raw, wake)` and `spin_once(timeout)`. Messages go in as rosbags message objects or as their
CDR payload (bytes, encapsulation header first, as `advperc_ros.ros.cdr` packs them), and come
out as rosbags objects, or with `raw=True` as the CDR payload, which the nodes read with `cdr`'s
decoders: the per-frame messages then never become rosbags objects (docs/graph.md,
"Performance"). Two transports provide that:

- `advperc_ros.ros.dds.DdsTransport`: Cyclone DDS with ROS 2's wire conventions, no ROS needed;
- `RclpyTransport` below: a real rclpy node. It hands rclpy CDR bytes (rclpy publishers accept
  serialised bytes) and subscribes with rclpy's own `raw=True`, decoding the bytes with rosbags
  unless asked for them raw, so the node logic sees the same messages, bit for bit, on both
  transports. Its node is spun by `NodeExecutor`, rclpy's wait set without the Python of rclpy's
  executors around it.

QoS is the contract's on both (`topics.depth`): reliable, volatile, keep-last 1000; latched topics are
transient-local, writers keep-last 1.
"""

import importlib
import time
from collections.abc import Callable
from typing import Any, Protocol

from advperc_ros.exceptions import MessageTypeMissing
from advperc_ros.ros.cdr import TYPESTORE, payload
from advperc_ros.ros.topics import depth

WAITABLES_PERIOD = 1.0
"""s between `NodeExecutor`'s waits on a node's waitables (QoS events, which only warn)."""


class Publisher(Protocol):
    """What a node publishes through, on either transport."""

    def publish(self, msg: object) -> None:
        """Send a rosbags message of the publisher's type, or its CDR payload (bytes) as it is."""

    def matched_count(self) -> int:
        """Subscribers currently matched (writer-side discovery)."""

    def wait_for_acks(self, timeout: float) -> bool:
        """Block until every matched reader has acknowledged everything published (all topics are
        reliable), so each holds it in its middleware before anything published after is sent; False
        when `timeout` s pass first. What lets the clock drive deliver a frame before its clock."""


class Transport(Protocol):
    """The only interface node logic and the graph backend see, so the same nodes run over rclpy and
    over bare Cyclone DDS, and tests can run them without ROS."""

    def publisher(self, topic: str, msgtype: str, latched: bool = False) -> Publisher:
        """A publisher of `topic` carrying `msgtype` (`pkg/msg/Type`)."""

    def subscriber(self, topic: str, msgtype: str, latched: bool = False,
                   callback: Callable[[Any], None] | None = None, raw: bool = False, wake: bool = True) -> object:
        """A subscription delivering rosbags messages to `callback` from `spin_once`; with `raw`,
        their CDR payloads (bytes) instead. `wake=False` is a hint that its messages need not end
        `spin_once`'s wait (they may wait for another message or the timeout): data read in bulk
        later need not cost a wake-up per message."""

    def spin_once(self, timeout: float) -> int:
        """Deliver pending messages to callbacks, waiting up to `timeout` s for the first."""

    def publishers_of(self, topic: str) -> tuple[str, ...] | None:
        """Full names of the ROS nodes publishing `topic`, where the middleware says (rclpy's graph
        API); None over bare DDS, which carries no node names (so "cannot tell" is not "nobody")."""

    def publisher_count(self, topic: str) -> int | None:
        """How many publishers of `topic` the middleware knows now, on either transport (over bare DDS:
        those matched by this transport's readers of it, None without one). A killed process's
        publishers leave once its DDS lease ends (Cyclone's default: 10 s)."""

    def node_names(self) -> tuple[str, ...] | None:
        """Full names of the ROS nodes in the graph now; None over bare DDS, as for `publishers_of`."""

    def best_effort_publishers(self, topic: str) -> tuple[str, ...] | None:
        """Full names of the nodes publishing `topic` best effort, which no reliable reader of ours
        matches (their messages never arrive); None where the transport cannot see a publisher's QoS
        (bare DDS: builtin-topic readers, the one way to, crash cyclonedds 11.0.1)."""


def _message_class(msgtype: str) -> Any:
    """The rclpy (rosidl) class of `pkg/msg/Type`: module `pkg.msg`, attribute `Type`."""
    package, kind, name = msgtype.split("/")
    try:
        return getattr(importlib.import_module(f"{package}.{kind}"), name)
    except ModuleNotFoundError:
        raise MessageTypeMissing(f"{msgtype}: this ROS 2 has no Python package '{package}'") from None


class _RclpyPublication:
    def __init__(self, publisher: Any, msgtype: str) -> None:
        self._publisher = publisher
        self._msgtype = msgtype

    def publish(self, msg: object) -> None:
        self._publisher.publish(payload(msg, self._msgtype))

    def matched_count(self) -> int:
        return int(self._publisher.get_subscription_count())

    def wait_for_acks(self, timeout: float) -> bool:
        from rclpy.duration import Duration

        return bool(self._publisher.wait_for_all_acked(Duration(nanoseconds=int(timeout * 1e9))))


def _full_name(endpoint: Any) -> str:
    """A graph endpoint's node as `ros2 node list` names it."""
    return f"{endpoint.node_namespace.rstrip('/')}/{endpoint.node_name}"


def _rclpy_qos(latched: bool, reader: bool = False) -> Any:
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=depth(latched, reader),
        reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE,
    )


def _finish(coroutine: Any) -> None:
    """Run to its end a coroutine that never waits: a waitable's `execute` with a plain callback."""
    try:
        coroutine.send(None)
    except StopIteration:
        return
    coroutine.close()
    raise RuntimeError("a waitable's callback awaited something: NodeExecutor runs plain callbacks only")


class NodeExecutor:
    """Runs one rclpy node's callbacks in the calling thread, straight from a wait set kept for the
    node's entities: what `rclpy.spin(node)` does, at a fraction of its cost per message.

    rclpy's SingleThreadedExecutor spends some 300 us of Python on every message it delivers
    (benchmarks/hop_cost.py, docs/graph.md "Performance"): for each callback it gathers the node's
    entities anew through their callback groups, enters every handle in a context manager, builds a
    new wait set, wraps the callback in a Task, and afterwards triggers its own guard condition,
    which wakes the next wait for nothing. A graph node runs plain callbacks on one thread, so none
    of that buys it anything: here the wait set is built again only when the node's entities
    change, every entity ready at a wake-up is served before the next wait, each subscription's
    queue is taken to its end, and callbacks are called directly. What a node sees is unchanged:
    the same rcl wait set, takes and callbacks, in one thread.

    Waitables join the wait once per `WAITABLES_PERIOD` (no wait then lasts longer): a graph node's
    are the QoS event handlers of its two dozen publishers and subscriptions, which only warn of an
    incompatible peer, yet rclpy's Python around them cost some 100 us per wait, more than the rest
    of the wait. A warning can so come up to a second late.

    Subscriptions marked `quiet` are not waited on but taken at every spin, woken or timed out: the
    graph client reads the per-frame topics only once a rollout is done (`Transport.subscriber`'s
    `wake=False`), and a wake-up for each would compete for the CPU with the nodes in every frame.

    It serves what the package's nodes hold: subscriptions (callbacks of one argument), timers,
    guard conditions, services (the parameter services `ros2 param` talks to) and waitables, all
    with plain callbacks; not service clients, whose responses complete futures. For one thread,
    like the node's callbacks.
    """

    def __init__(self, node: Any) -> None:
        from rclpy.guard_condition import GuardCondition

        self._node = node
        self._context = node.context
        # a shutdown from elsewhere (another thread, a signal handler) ends the wait it finds
        self._wake = GuardCondition(None, None, context=self._context)
        self._context.on_shutdown(self._wake.trigger)
        self._quiet: set[Any] = set()
        self._waitables_due = 0.0  # time.monotonic() of the next wait on the waitables
        self._build(self._gather())

    def quiet(self, subscription: Any) -> None:
        """Take `subscription`'s messages at every spin without waking for them."""
        self._quiet.add(subscription)
        self._entities = ()  # built again at the next spin

    def _gather(self) -> tuple:
        node = self._node
        return (tuple(node.subscriptions), tuple(node.timers), tuple(node.guards), tuple(node.services),
                tuple(node.waitables))

    def _build(self, entities: tuple) -> None:
        from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
        from rclpy.waitable import NumberOfEntities

        everything, timers, guards, services, waitables = entities
        subscriptions = [s for s in everything if s not in self._quiet]
        count = NumberOfEntities(len(subscriptions), len(guards) + 1, len(timers), 0, len(services))
        for waitable in waitables:
            count += waitable.get_num_entities()
        self._wait_set = _rclpy.WaitSet(count.num_subscriptions, count.num_guard_conditions, count.num_timers,
                                        count.num_clients, count.num_services, count.num_events, self._context.handle)
        self._entities = entities
        self._handles = ([s.handle for s in subscriptions], [t.handle for t in timers],
                         [g.handle for g in guards] + [self._wake.handle], [s.handle for s in services])
        self._subscriptions = {s.handle.pointer: s for s in subscriptions}
        self._quiet_now = [s for s in everything if s in self._quiet]
        self._timers = {t.handle.pointer: t for t in timers}
        self._guards = {g.handle.pointer: g for g in guards}
        self._services = {s.handle.pointer: s for s in services}
        self._waitables = waitables

    def spin_once(self, timeout: float | None = None) -> None:
        """Wait up to `timeout` s (None: for ever) for work, then do all there is. Raises rclpy's
        ExternalShutdownException if the context was shut down meanwhile, as rclpy's executors do."""
        from rclpy.executors import ExternalShutdownException

        entities = self._gather()
        if entities != self._entities:
            self._build(entities)
        now = time.monotonic()
        waitables = self._waitables if now >= self._waitables_due else ()
        if waitables:
            self._waitables_due = now + WAITABLES_PERIOD
        elif timeout is None or timeout < 0 or timeout > self._waitables_due - now:
            timeout = self._waitables_due - now
        wait_set = self._wait_set
        wait_set.clear_entities()
        subscriptions, timers, guards, services = self._handles
        for handle in subscriptions:
            wait_set.add_subscription(handle)
        for handle in timers:
            wait_set.add_timer(handle)
        for handle in guards:
            wait_set.add_guard_condition(handle)
        for handle in services:
            wait_set.add_service(handle)
        for waitable in waitables:
            waitable.add_to_wait_set(wait_set)
        wait_set.wait(-1 if timeout is None or timeout < 0 else int(timeout * 1e9))
        if not self._context.ok():
            raise ExternalShutdownException()
        for pointer in wait_set.get_ready_entities("timer"):
            timer = self._timers[pointer]
            if timer.handle.is_timer_ready():  # rcl may report a cancelled timer
                timer.handle.call_timer()
                timer.callback()
        for subscription in [self._subscriptions[p] for p in wait_set.get_ready_entities("subscription")] + self._quiet_now:
            take, msg_type, raw, callback = (subscription.handle.take_message, subscription.msg_type, subscription.raw,
                                             subscription.callback)
            while (taken := take(msg_type, raw)) is not None:
                callback(taken[0])
        for pointer in wait_set.get_ready_entities("service"):
            service = self._services[pointer]
            request, header = service.handle.service_take_request(service.srv_type.Request)
            if header is not None:
                service.send_response(service.callback(request, service.srv_type.Response()), header)
        for waitable in waitables:
            if waitable.is_ready(wait_set):
                _finish(waitable.execute(waitable.take_data()))
        for pointer in wait_set.get_ready_entities("guard_condition"):  # last: one may shut the context down
            guard = self._guards.get(pointer)  # not there: this executor's own wake-up
            if guard is not None:
                guard.callback()

    def spin(self) -> None:
        """Serve the node until its context shuts down (`rclpy.spin(node)`)."""
        while self._context.ok():
            self.spin_once()


class RclpyTransport:
    """The transport interface on an rclpy node (needs ROS 2 sourced; rclpy is imported here)."""

    def __init__(self, node: Any) -> None:
        self._node = node
        self._delivered = 0
        self._executor: NodeExecutor | None = None  # made when first needed (a transport that only publishes needs none)

    def publisher(self, topic: str, msgtype: str, latched: bool = False) -> _RclpyPublication:
        return _RclpyPublication(self._node.create_publisher(_message_class(msgtype), topic, _rclpy_qos(latched)), msgtype)

    def subscriber(self, topic: str, msgtype: str, latched: bool = False,
                   callback: Callable[[Any], None] | None = None, raw: bool = False, wake: bool = True) -> object:
        """As the protocol says; with `wake=False` this transport's executor takes the messages
        without waking for them (`NodeExecutor.quiet`)."""
        if callback is None:
            raise ValueError(f"{topic}: rclpy subscriptions deliver through a callback; give one")

        def deliver(data: bytes) -> None:
            self._delivered += 1
            callback(data if raw else TYPESTORE.deserialize_cdr(data, msgtype))

        subscription = self._node.create_subscription(_message_class(msgtype), topic, deliver,
                                                      _rclpy_qos(latched, reader=True), raw=True)
        if not wake:
            self.executor.quiet(subscription)
        return subscription

    def publishers_of(self, topic: str) -> tuple[str, ...]:
        return tuple(sorted({_full_name(info) for info in self._node.get_publishers_info_by_topic(topic)}))

    def publisher_count(self, topic: str) -> int:
        return int(self._node.count_publishers(topic))

    def best_effort_publishers(self, topic: str) -> tuple[str, ...]:
        from rclpy.qos import ReliabilityPolicy

        return tuple(sorted({_full_name(info) for info in self._node.get_publishers_info_by_topic(topic)
                             if info.qos_profile.reliability == ReliabilityPolicy.BEST_EFFORT}))

    def node_names(self) -> tuple[str, ...]:
        return tuple(sorted(f"{namespace.rstrip('/')}/{name}"
                            for name, namespace in self._node.get_node_names_and_namespaces()))

    @property
    def executor(self) -> NodeExecutor:
        """The one executor holding this transport's node (`rclpy.spin_once(node)` would add and
        remove the node on every call, rebuilding the wait set each time)."""
        if self._executor is None:
            self._executor = NodeExecutor(self._node)
        return self._executor

    def spin_once(self, timeout: float) -> int:
        before = self._delivered
        self.executor.spin_once(timeout)
        return self._delivered - before
