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
  transports.

QoS is the contract's on both (`topics.depth`): reliable, volatile, keep-last 1000; latched topics are
transient-local, writers keep-last 1.
"""

import importlib
from collections.abc import Callable
from typing import Any, Protocol

from advperc_ros.ros.cdr import TYPESTORE, payload
from advperc_ros.ros.topics import depth


class Publisher(Protocol):
    def publish(self, msg: object) -> None:
        """Send a rosbags message of the publisher's type, or its CDR payload (bytes) as it is."""

    def matched_count(self) -> int:
        """Subscribers currently matched (writer-side discovery)."""


class Transport(Protocol):
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

    def node_names(self) -> tuple[str, ...] | None:
        """Full names of the ROS nodes in the graph now; None over bare DDS, as for `publishers_of`."""


def _message_class(msgtype: str) -> Any:
    """The rclpy (rosidl) class of `pkg/msg/Type`: module `pkg.msg`, attribute `Type`."""
    package, kind, name = msgtype.split("/")
    return getattr(importlib.import_module(f"{package}.{kind}"), name)


class _RclpyPublication:
    def __init__(self, publisher: Any, msgtype: str) -> None:
        self._publisher = publisher
        self._msgtype = msgtype

    def publish(self, msg: object) -> None:
        self._publisher.publish(payload(msg, self._msgtype))

    def matched_count(self) -> int:
        return int(self._publisher.get_subscription_count())


def _rclpy_qos(latched: bool, reader: bool = False) -> Any:
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=depth(latched, reader),
        reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE,
    )


class RclpyTransport:
    """The transport interface on an rclpy node (needs ROS 2 sourced; rclpy is imported here)."""

    def __init__(self, node: Any) -> None:
        self._node = node
        self._delivered = 0
        self._executor: Any = None  # made by the first spin_once (a node that rclpy.spin()s needs none)

    def publisher(self, topic: str, msgtype: str, latched: bool = False) -> _RclpyPublication:
        return _RclpyPublication(self._node.create_publisher(_message_class(msgtype), topic, _rclpy_qos(latched)), msgtype)

    def subscriber(self, topic: str, msgtype: str, latched: bool = False,
                   callback: Callable[[Any], None] | None = None, raw: bool = False, wake: bool = True) -> object:
        """As the protocol says; `wake` is not used (an rclpy executor wakes for every message)."""
        if callback is None:
            raise ValueError(f"{topic}: rclpy subscriptions deliver through a callback; give one")

        def deliver(data: bytes) -> None:
            self._delivered += 1
            callback(data if raw else TYPESTORE.deserialize_cdr(data, msgtype))

        return self._node.create_subscription(_message_class(msgtype), topic, deliver, _rclpy_qos(latched, reader=True),
                                              raw=True)

    def publishers_of(self, topic: str) -> tuple[str, ...]:
        return tuple(sorted({f"{info.node_namespace.rstrip('/')}/{info.node_name}"
                             for info in self._node.get_publishers_info_by_topic(topic)}))

    def node_names(self) -> tuple[str, ...]:
        return tuple(sorted(f"{namespace.rstrip('/')}/{name}"
                            for name, namespace in self._node.get_node_names_and_namespaces()))

    def spin_once(self, timeout: float) -> int:
        before = self._delivered
        if self._executor is None:
            # one executor holding the node for good: rclpy.spin_once(node) adds and removes the node
            # on every call, and each of those rebuilds the wait set and wakes the next wait for nothing
            from rclpy.executors import SingleThreadedExecutor

            self._executor = SingleThreadedExecutor(context=self._node.context)
            self._executor.add_node(self._node)
        self._executor.spin_once(timeout_sec=timeout)
        return self._delivered - before
