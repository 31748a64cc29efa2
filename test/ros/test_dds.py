"""The Cyclone DDS transport: wire compatibility with ROS 2 and delivery over loopback.

All DDS traffic stays on 127.0.0.1 (localhost_only=True) and each test uses a domain id of its
own, derived from this process's pid (100..199, never ROS's default 0).
"""

import dataclasses
import os
import subprocess
import sys
import time

import numpy as np
import pytest

pytest.importorskip("cyclonedds", reason="cyclonedds (PyPI) is not installed; the DDS transport needs it")

from advperc_ros.core.planners.base import Trajectory  # noqa: E402
from advperc_ros.core.scenario import EgoState  # noqa: E402
from advperc_ros.exceptions import DdsError  # noqa: E402
from advperc_ros.ros import dds, dds_types  # noqa: E402
from advperc_ros.ros import messages as msgs  # noqa: E402
from advperc_ros.ros.topics import TRACKING  # noqa: E402
from advperc_ros.ros.topics import LATCHED, PERCEPTION, SUMMARY, TOPIC_TYPES
from conftest import REPO, bare_dds_domains  # noqa: E402

T0 = 1_700_000_000_123_456_789
TIMEOUT = 5.0
_domain_ids = bare_dds_domains(0)


@pytest.fixture
def domain_id() -> int:
    """A fresh domain id per test, never shared with a test running at the same time."""
    value = next(_domain_ids)
    assert 100 <= value < 200
    return value


def _boxes() -> dict[str, np.ndarray]:
    return {
        "ids": np.array([3, 17]),
        "x": np.array([10.5, -4.25]),
        "y": np.array([2.0, 7.75]),
        "yaw": np.array([0.3, -2.9]),
        "vx": np.array([5.0, 0.0]),
        "vy": np.array([-0.5, 1.25]),
        "length": np.array([4.5, 0.8]),
        "width": np.array([1.9, 0.6]),
        "height": np.array([1.5, 1.8]),
        "score": np.array([0.875, np.nan]),  # a detection confidence, and none (ground truth)
    }


def contract_messages() -> list[tuple[str, str, object]]:
    """(topic, type, representative message) for every contract message type."""
    plan = Trajectory(
        t=np.array([0.0, 0.1, 0.2]), x=np.array([0.0, 1.0, 2.1]), y=np.array([0.0, 0.05, 0.2]), yaw=np.array([0.0, 0.05, 0.1])
    )
    return [
        ("/perception/objects", TOPIC_TYPES[PERCEPTION], msgs.objects_to_markers(_boxes(), T0, "perception")),
        ("/ego/odometry", "nav_msgs/msg/Odometry", msgs.odometry(EgoState(x=1.5, y=-2.0, yaw=0.7, v=8.25), T0)),
        ("/planning/trajectory", "nav_msgs/msg/Path", msgs.trajectory_to_path(plan, T0)),
        ("/clock", "rosgraph_msgs/msg/Clock", msgs.clock(T0)),
        ("/ego/footprint", "geometry_msgs/msg/PolygonStamped",
         msgs.TYPESTORE.deserialize_cdr(msgs.footprint_cdr(4.6, 1.9, T0), "geometry_msgs/msg/PolygonStamped")),
        ("/rules/collision", "std_msgs/msg/Float64", msgs.float64(-1.625)),
        ("/attack/summary", "std_msgs/msg/String", msgs.string("rollout 3: collision at t=4.2 s, ünïcode")),
        (
            "/rules/diagnostics",
            "diagnostic_msgs/msg/DiagnosticArray",
            msgs.diagnostics(T0, "collision", "signed distance", {"distance": "-1.625", "frame": "42"}, level=1),
        ),
    ]


def _ids(cases: list) -> list[str]:
    return [msgtype.rsplit("/", 1)[-1] for _, msgtype, _ in cases]


def edge_values_message() -> object:
    """A MarkerArray with values at the edges of their wire types: a wrong integer width or
    signedness, or a bool carried as a number, cannot round-trip it unnoticed."""
    msg = msgs.objects_to_markers(_boxes(), T0, "tracking")
    marker = msg.markers[1]
    marker.header.stamp.sec = -(2**31)
    marker.header.stamp.nanosec = 2**32 - 1
    marker.id = 2**31 - 1
    marker.lifetime.sec = 2**31 - 1
    marker.frame_locked = True
    marker.mesh_use_embedded_materials = True
    marker.texture.data = np.arange(256, dtype=np.uint8)
    marker.mesh_file.data = np.array([0, 255, 7], dtype=np.uint8)
    marker.colors = [msgs.T["std_msgs/msg/ColorRGBA"](r=3.4e38, g=-1.5, b=1e-45, a=0.0)]
    marker.uv_coordinates = [msgs.T["visualization_msgs/msg/UVCoordinate"](u=0.25, v=0.75)]
    marker.pose.position.x = 1.7976931348623157e308
    return msg


CASES = contract_messages()
WIRE_CASES = [*CASES, ("/tracking/objects", TOPIC_TYPES[TRACKING], edge_values_message()),
              ("/localization/acceleration", msgs.ACCELERATION,  # the Autoware profiles' (not a contract topic)
               msgs.TYPESTORE.deserialize_cdr(msgs.acceleration_cdr(-2.5, T0), msgs.ACCELERATION)),
              ("/tf", msgs.TRANSFORMS,  # the Autoware profiles' too
               msgs.TYPESTORE.deserialize_cdr(msgs.transform_cdr(EgoState(12.5, -3.25, 0.4, 9.0), T0), msgs.TRANSFORMS))]


def test_contract_covers_every_topic_type():
    assert {msgtype for _, msgtype, _ in CASES} == set(TOPIC_TYPES.values())


def _field_names(msg: object) -> list[str]:
    return [name for name, _ in msgs.TYPESTORE.fielddefs[msg.__msgtype__][1]]


def canonical(msg: object, msgtype: str) -> object:
    """The message as it is on the wire (rosbags' own decode of its CDR: float32 fields rounded)."""
    return msgs.TYPESTORE.deserialize_cdr(msgs.TYPESTORE.serialize_cdr(msg, msgtype), msgtype)


def _build_idl(value: object) -> object:
    """A rosbags message as an IDL sample, built field by field (independently of the bytes)."""
    if dataclasses.is_dataclass(value):
        cls = dds_types.idl_type(value.__msgtype__)
        return cls(**{name: _build_idl(getattr(value, name)) for name in _field_names(value)})
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, list):
        return [_build_idl(v) for v in value]
    return value


def assert_same(a: object, b: object, where: str = "msg") -> None:
    """Field-by-field equality of two rosbags messages (numpy arrays with array_equal)."""
    if dataclasses.is_dataclass(a):
        assert a.__msgtype__ == b.__msgtype__, where
        for name in _field_names(a):
            assert_same(getattr(a, name), getattr(b, name), f"{where}.{name}")
    elif isinstance(a, np.ndarray):
        assert isinstance(b, np.ndarray) and a.dtype == b.dtype and np.array_equal(a, b), where
    elif isinstance(a, list):
        assert isinstance(b, list) and len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b)):
            assert_same(x, y, f"{where}[{i}]")
    else:
        assert type(a) is type(b) and a == b, f"{where}: {a!r} != {b!r}"


@pytest.mark.parametrize(("topic", "msgtype", "msg"), WIRE_CASES, ids=[*_ids(CASES), "MarkerArray-edge-values", "AccelWithCovarianceStamped", "TFMessage"])
def test_idl_serialisation_equals_rosbags_cdr(topic, msgtype, msg):
    """The wire-compatibility proof: Cyclone's CDR of the generated type is rosbags' (= ROS 2's)."""
    expected = bytes(msgs.TYPESTORE.serialize_cdr(msg, msgtype))
    sample = _build_idl(msg)
    assert type(sample).__idl_typename__ == dds_types.dds_type_name(msgtype)
    assert sample.serialize(use_version_2=False) == expected
    assert expected[:4] == b"\x00\x01\x00\x00"  # plain CDR, little endian
    # and the conversions both ways, through those bytes
    decoded = dds_types.to_idl(msg, msgtype)
    assert decoded == _build_idl(canonical(msg, msgtype))
    if msgtype == TOPIC_TYPES[TRACKING]:
        assert type(decoded.markers[1].frame_locked) is bool
    assert_same(dds_types.from_idl(sample, msgtype), canonical(msg, msgtype))


def test_dds_type_names_follow_ros2():
    assert dds_types.dds_type_name("visualization_msgs/msg/MarkerArray") == "visualization_msgs::msg::dds_::MarkerArray_"
    nested = dds_types.IDL_TYPES["visualization_msgs/msg/Marker"]
    assert nested.__idl_typename__ == "visualization_msgs::msg::dds_::Marker_"
    assert dds_types.IDL_TYPES["sensor_msgs/msg/CompressedImage"].__idl_typename__ == "sensor_msgs::msg::dds_::CompressedImage_"
    assert dds.dds_topic_name("/perception/objects") == "rt/perception/objects"


def _round_trip_all(domain_id: int) -> None:
    with dds.DdsTransport(domain_id, localhost_only=True) as sender, dds.DdsTransport(domain_id, localhost_only=True) as receiver:
        pairs = []
        for topic, msgtype, msg in CASES:
            subscription = receiver.subscriber(topic, msgtype)
            publication = sender.publisher(topic, msgtype)
            pairs.append((publication, subscription, canonical(msg, msgtype)))
        for publication, _, _ in pairs:
            assert publication.wait_for_subscribers(1, TIMEOUT), publication.topic
        for publication, _, msg in pairs:
            publication.publish(msg)
            publication.publish(msg)
        for publication, subscription, msg in pairs:
            received = subscription.wait(TIMEOUT)
            while len(received) < 2:
                more = subscription.wait(TIMEOUT)
                assert more, f"{subscription.topic}: got {len(received)} of 2 messages"
                received += more
            assert len(received) == 2, subscription.topic
            for got in received:
                assert_same(got, msg, subscription.topic)


def test_round_trip_every_type_one_process(domain_id):
    _round_trip_all(domain_id)


@pytest.mark.parametrize("public", [("_ddspy_write",), ("_ddspy_take",), ("_ddspy_write", "_ddspy_take")])
def test_round_trip_through_public_cyclonedds_api(domain_id, monkeypatch, public):
    """The fallback for a cyclonedds without the raw write/take functions, also mixed with the
    fast path (a padded payload with padding bits set must decode both ways)."""
    for name in public:
        monkeypatch.setattr(dds, name, None)
    _round_trip_all(domain_id)


def test_latched_topic_reaches_late_subscriber_and_callbacks_spin(domain_id):
    assert SUMMARY in LATCHED
    msgtype = TOPIC_TYPES[SUMMARY]
    with dds.DdsTransport(domain_id) as sender, dds.DdsTransport(domain_id) as receiver:
        publication = sender.publisher(SUMMARY, msgtype, latched=True)
        publication.publish(msgs.string("old"))
        publication.publish(msgs.string("last"))
        got: list[str] = []
        receiver.subscriber(SUMMARY, msgtype, latched=True, callback=lambda m: got.append(m.data))
        deadline = time.monotonic() + TIMEOUT
        while not got and time.monotonic() < deadline:
            receiver.spin_once(0.5)
        assert got == ["last"]  # depth 1: only the latest
        assert receiver.spin_once(0.05) == 0


def test_topic_type_mismatch_is_an_error(domain_id):
    with dds.DdsTransport(domain_id) as transport:
        transport.publisher("/clock", "rosgraph_msgs/msg/Clock")
        with pytest.raises(DdsError, match="/clock"):
            transport.subscriber("/clock", "std_msgs/msg/String")


def test_two_processes_exchange_marker_array(domain_id):
    """A MarkerArray to another OS process and its echo and reply back, all within timeouts."""
    _, msgtype, msg = CASES[0]
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]))
    with dds.DdsTransport(domain_id, localhost_only=True) as transport:
        objects = transport.publisher(PERCEPTION, msgtype)
        echo = transport.subscriber(TRACKING, msgtype)
        reply = transport.subscriber(SUMMARY, TOPIC_TYPES[SUMMARY])
        peer = subprocess.Popen(
            [sys.executable, str(REPO / "test" / "dds_peer.py"), str(domain_id), str(TIMEOUT)],
            cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        )
        try:
            assert objects.wait_for_subscribers(1, 2 * TIMEOUT), "peer never subscribed"
            objects.publish(msg)
            echoed = echo.wait(TIMEOUT)
            replies = reply.wait(TIMEOUT)
            out, err = peer.communicate(timeout=TIMEOUT)
        finally:
            if peer.poll() is None:
                peer.kill()
                peer.communicate()
        assert peer.returncode == 0, f"peer exited {peer.returncode}: {err}"
        assert len(echoed) == 1
        assert_same(echoed[0], canonical(msg, msgtype))
        assert [m.data for m in replies] == [f"received {len(msg.markers)} markers"]
