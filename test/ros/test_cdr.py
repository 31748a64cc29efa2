"""The CDR codecs of the per-frame messages: the bytes are rosbags' (= ROS 2's), field by field,
and the decoders read any valid message of the type, not only what the encoders write."""

import dataclasses
import math

import numpy as np
import pytest

from advperc_ros.core.planners.base import Trajectory
from advperc_ros.core.scenario import EgoState
from advperc_ros.exceptions import MessageError
from advperc_ros.ros import cdr
from advperc_ros.ros import messages as msgs
from advperc_ros.ros.lockstep import plan_from_cdr

TS = cdr.TYPESTORE
T = TS.types
T0 = 1_700_000_000_123_456_789


def boxes(count: int, scored: bool, seed: int = 0) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    out = {name: rng.normal(0.0, 20.0, count) for name in ("x", "y", "vx", "vy", "length", "width", "height")}
    out["yaw"] = rng.uniform(-np.pi, np.pi, count)
    out["ids"] = rng.permutation(10_000)[:count].astype(np.int64)
    out["score"] = rng.uniform(0.0, 1.0, count) if scored else np.full(count, np.nan)
    if scored and count:
        out["score"][0] = np.nan  # a detection without confidence: empty text
    return out


def reserialised(data: bytes, msgtype: str) -> bytes:
    return bytes(TS.serialize_cdr(TS.deserialize_cdr(data, msgtype), msgtype))


@pytest.mark.parametrize("count", [0, 1, 2, 7])
@pytest.mark.parametrize("kind", ["ground_truth", "perception", "tracking"])
@pytest.mark.parametrize("stamp", [T0, 0, -1_500_000_001])
def test_object_markers_are_rosbags_bytes_of_the_convention(count, kind, stamp):
    objects = boxes(count, scored=kind == "perception", seed=count)
    data = cdr.encode_objects(objects, stamp, kind)
    assert data == reserialised(data, cdr.MARKER_ARRAY)  # canonical: padding, alignment, lengths
    markers = TS.deserialize_cdr(data, cdr.MARKER_ARRAY).markers
    assert len(markers) == 1 + 2 * count
    assert markers[0].action == cdr.DELETEALL and msgs.stamp_ns(markers[0].header.stamp) == stamp
    for i, (cube, arrow) in enumerate(zip(markers[1::2], markers[2::2])):
        for marker in (cube, arrow):
            assert marker.header.frame_id == "map" and msgs.stamp_ns(marker.header.stamp) == stamp
            assert marker.id == objects["ids"][i] and marker.action == cdr.ADD
            assert (marker.color.r, marker.color.a) == tuple(np.float32(cdr.COLORS[kind])[[0, 3]])
        assert (cube.ns, cube.type, arrow.ns, arrow.type) == ("objects", cdr.CUBE, "velocity", cdr.ARROW)
        position = cube.pose.position
        assert (position.x, position.y, position.z) == (objects["x"][i], objects["y"][i], objects["height"][i] / 2)
        assert cube.pose.orientation.z == pytest.approx(np.sin(objects["yaw"][i] / 2), abs=1e-15)
        scale = (cube.scale.x, cube.scale.y, cube.scale.z)
        assert scale == (objects["length"][i], objects["width"][i], objects["height"][i])
        score = objects["score"][i]
        assert cube.text == (repr(float(score)) if np.isfinite(score) else "")
        tip = arrow.points[1]
        assert (tip.x, tip.y) == (objects["x"][i] + objects["vx"][i], objects["y"][i] + objects["vy"][i])
    got_stamp, got = cdr.decode_objects(data, "test")
    assert got_stamp == stamp
    order = np.argsort(objects["ids"])
    assert np.array_equal(got["ids"], objects["ids"][order])
    for name in ("x", "y", "length", "width", "height", "score"):
        assert np.array_equal(got[name], objects[name][order], equal_nan=True), name
    for name in ("yaw", "vx", "vy"):
        np.testing.assert_allclose(got[name], objects[name][order], rtol=0, atol=1e-12)


def any_marker_array() -> object:
    """A MarkerArray with everything the encoders leave empty filled in (strings of every length,
    colours, textures, uv coordinates, meshes), a cube without an arrow and an arrow of three
    points (both read as velocity 0)."""
    msg = msgs.objects_to_markers(boxes(3, scored=True, seed=5), T0, "perception")
    for k, marker in enumerate(msg.markers):
        marker.header.frame_id = "m" * k
        marker.colors = [T["std_msgs/msg/ColorRGBA"](r=0.5, g=0.25, b=0.0, a=1.0)] * k
        marker.texture_resource = "x" * (k % 4)
        marker.texture.header.frame_id = "tex" * k
        marker.texture.format = "png"[: k % 4]
        marker.texture.data = np.arange(k, dtype=np.uint8)
        marker.uv_coordinates = [T["visualization_msgs/msg/UVCoordinate"](u=0.25, v=0.75)] * (k % 3)
        marker.mesh_resource = "package://m" * (k % 2)
        marker.mesh_file.filename = "f" * (k % 5)
        marker.mesh_file.data = np.arange(k % 7, dtype=np.uint8)
        marker.mesh_use_embedded_materials = bool(k % 2)
    msg.markers.append(dataclasses.replace(msg.markers[1], id=99, text=""))
    msg.markers[2].points.append(msg.markers[2].points[0])
    return msg


def expected_objects(msg) -> dict[str, np.ndarray]:
    """The object convention read field by field from rosbags objects (the decoder's oracle)."""
    cubes = {int(m.id): m for m in msg.markers if m.ns == "objects" and m.action != cdr.DELETEALL}
    arrows = {int(m.id): m.points for m in msg.markers if m.ns == "velocity"}
    ids = sorted(cubes)
    out = {"ids": np.array(ids, dtype=np.int64)}
    out["x"] = np.array([cubes[i].pose.position.x for i in ids])
    out["y"] = np.array([cubes[i].pose.position.y for i in ids])
    out["yaw"] = np.array([2 * np.arctan2(cubes[i].pose.orientation.z, cubes[i].pose.orientation.w) for i in ids])
    for name, axis in (("length", "x"), ("width", "y"), ("height", "z")):
        out[name] = np.array([getattr(cubes[i].scale, axis) for i in ids])
    out["score"] = np.array([float(cubes[i].text) if cubes[i].text else np.nan for i in ids])
    for name, axis in (("vx", "x"), ("vy", "y")):
        points = [arrows.get(i, []) for i in ids]
        out[name] = np.array([getattr(p[1], axis) - getattr(p[0], axis) if len(p) == 2 else 0.0 for p in points])
    return out


def test_objects_decoder_reads_any_marker_array_in_either_byte_order():
    msg = any_marker_array()
    expected = expected_objects(msg)
    assert 99 in expected["ids"] and np.count_nonzero(expected["vx"] == 0.0) == 2
    for little_endian in (True, False):
        data = bytes(TS.serialize_cdr(msg, cdr.MARKER_ARRAY, little_endian=little_endian))
        stamp, got = cdr.decode_objects(data + b"\0\0", "test")  # DDS pads payloads to 4 bytes
        assert stamp == T0 and got.keys() == expected.keys()
        for name, values in expected.items():
            np.testing.assert_allclose(got[name], values, rtol=0, atol=1e-12, err_msg=name)


def test_objects_decoder_names_what_is_wrong():
    data = cdr.encode_objects(boxes(2, scored=False), T0, "tracking")
    with pytest.raises(MessageError, match="where: a MarkerArray cut short"):
        cdr.decode_objects(data[:-40], "where")
    with pytest.raises(MessageError, match="where: not a plain CDR payload"):
        cdr.decode_objects(b"\x00\x03" + data[2:], "where")
    msg = msgs.objects_to_markers(boxes(1, scored=False), T0, "tracking")
    msg.markers[1].text = "high"
    with pytest.raises(MessageError, match="where: field 'text' of marker .* 'high'"):
        cdr.decode_objects(bytes(TS.serialize_cdr(msg, cdr.MARKER_ARRAY)), "where")
    assert cdr.decode_objects(bytes(TS.serialize_cdr(T["visualization_msgs/msg/MarkerArray"](markers=[]), cdr.MARKER_ARRAY)),
                              "where")[0] is None


@pytest.mark.parametrize("count", [0, 1, 2, 81])
def test_paths_are_rosbags_bytes_and_decode_to_the_plan(count):
    rng = np.random.default_rng(count)
    plan = Trajectory(t=np.cumsum(rng.uniform(0.01, 0.2, count)), x=rng.normal(0, 100, count),
                      y=rng.normal(0, 100, count), yaw=rng.uniform(-np.pi, np.pi, count))
    data = msgs.trajectory_cdr(plan, T0)
    assert data == reserialised(data, cdr.PATH)
    path = TS.deserialize_cdr(data, cdr.PATH)
    assert msgs.stamp_ns(path.header.stamp) == T0 and path.header.frame_id == "map"
    offsets = [int(round(t * 1e9)) for t in plan.t]
    assert [msgs.stamp_ns(p.header.stamp) for p in path.poses] == [T0 - offsets[0] + o for o in offsets]
    assert all(p.header.frame_id == "map" for p in path.poses)
    assert [p.pose.position.x for p in path.poses] == list(plan.x)
    stamp, got = plan_from_cdr(data, T0 - 5_000_000_000, "test")
    assert stamp == T0
    np.testing.assert_allclose(got.t, plan.t - plan.t[:1] + 5.0, rtol=0, atol=1e-9)
    assert np.array_equal(got.x, plan.x) and np.array_equal(got.y, plan.y)
    np.testing.assert_allclose(got.yaw, plan.yaw, rtol=0, atol=1e-12)


def test_path_decoder_reads_any_path_in_either_byte_order():
    data = cdr.encode_path([1.0, 2.0, 3.0], [4.0, 5.0, 6.0], [0.1, -3.0, 2.5], [T0, T0 + 1, T0 + 2], T0)
    path = TS.deserialize_cdr(data, cdr.PATH)
    for k, pose in enumerate(path.poses):
        pose.header.frame_id = "f" * (3 * k)  # frame ids of other lengths shift every later pose
        pose.pose.position.z = 7.0
        pose.pose.orientation = T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=np.sin(0.3), w=np.cos(0.3))
    for little_endian in (True, False):
        data = bytes(TS.serialize_cdr(path, cdr.PATH, little_endian=little_endian))
        stamp, poses, stamps = cdr.decode_path(data, "test")
        assert stamp == T0 and list(stamps) == [T0, T0 + 1, T0 + 2]
        np.testing.assert_allclose(poses, [[1.0, 4.0, 0.6], [2.0, 5.0, 0.6], [3.0, 6.0, 0.6]], rtol=0, atol=1e-12)
        with pytest.raises(MessageError, match="where: .*Path"):
            cdr.decode_path(data[:-8], "where")
    bogus = bytearray(cdr.encode_path([1.0, 2.0], [1.0, 2.0], [0.0, 0.0], [T0, T0 + 1], T0))
    bogus[32:36] = (2**31).to_bytes(4, "little")  # first pose: encapsulation, header, count, stamp, then this
    with pytest.raises(MessageError, match="where: a Path cut short"):
        cdr.decode_path(bytes(bogus), "where")


def test_odometry_and_clock_are_rosbags_bytes():
    data = cdr.encode_odometry(1.5, -2.0, 0.7, 8.25, T0)
    assert data == reserialised(data, cdr.ODOMETRY)
    msg = TS.deserialize_cdr(data, cdr.ODOMETRY)
    assert msgs.stamp_ns(msg.header.stamp) == T0 and (msg.header.frame_id, msg.child_frame_id) == ("map", "base_link")
    pose, twist = msg.pose.pose, msg.twist.twist
    assert (pose.position.x, pose.position.y, pose.position.z) == (1.5, -2.0, 0.0)
    assert (pose.orientation.z, pose.orientation.w) == (np.sin(0.35), np.cos(0.35))
    assert (twist.linear.x, twist.linear.y, twist.angular.z) == (8.25, 0.0, 0.0)
    assert not msg.pose.covariance.any() and not msg.twist.covariance.any()
    clock = cdr.encode_clock(T0)
    assert clock == reserialised(clock, "rosgraph_msgs/msg/Clock")
    assert msgs.stamp_ns(TS.deserialize_cdr(clock, "rosgraph_msgs/msg/Clock").clock) == T0


def test_odometry_decoder_reads_any_odometry_in_either_byte_order():
    msg = msgs.odometry(EgoState(1.5, -2.0, 0.7, 8.25), T0)
    msg.header.frame_id, msg.child_frame_id = "world", "ego_vehicle"
    msg.pose.covariance = np.arange(36, dtype=float)
    msg.twist.twist.angular.z = 0.5
    for little_endian in (True, False):
        data = bytes(TS.serialize_cdr(msg, cdr.ODOMETRY, little_endian=little_endian))
        stamp, (x, y, yaw, speed) = cdr.decode_odometry(data, "test")
        assert (stamp, x, y, speed) == (T0, 1.5, -2.0, 8.25) and yaw == pytest.approx(0.7, abs=1e-15)
    with pytest.raises(MessageError, match="where: an Odometry cut short"):
        cdr.decode_odometry(bytes(TS.serialize_cdr(msg, cdr.ODOMETRY))[:-400], "where")


def test_diagnostics_are_rosbags_bytes_and_read_in_either_byte_order():
    status = cdr.Status(2, "collision", "violated", "advperc", {"min_signed_distance": "-1.5", "agent 3": "inf", "ü": ""})
    data = cdr.encode_diagnostics(T0, status)
    assert data == reserialised(data, cdr.DIAGNOSTICS)
    msg = TS.deserialize_cdr(data, cdr.DIAGNOSTICS)
    assert msgs.stamp_ns(msg.header.stamp) == T0 and msg.header.frame_id == "map" and len(msg.status) == 1
    assert (msg.status[0].level, msg.status[0].name, msg.status[0].message, msg.status[0].hardware_id) == status[:4]
    assert {kv.key: kv.value for kv in msg.status[0].values} == status.values
    bare = status._replace(values={})
    assert cdr.decode_diagnostics(cdr.encode_diagnostics(T0, bare), "test") == (T0, [bare])
    # statuses after the first follow unaligned (a status starts with a byte)
    msg.status.append(T["diagnostic_msgs/msg/DiagnosticStatus"](level=1, name="abcde", message="", hardware_id="x",
                                                                values=[]))
    msg.status.append(T["diagnostic_msgs/msg/DiagnosticStatus"](
        level=3, name="", message="m", hardware_id="", values=[T["diagnostic_msgs/msg/KeyValue"](key="k", value="vvv")]))
    expected = [status, cdr.Status(1, "abcde", "", "x", {}), cdr.Status(3, "", "m", "", {"k": "vvv"})]
    for little_endian in (True, False):
        data = bytes(TS.serialize_cdr(msg, cdr.DIAGNOSTICS, little_endian=little_endian))
        assert cdr.decode_diagnostics(data, "test") == (T0, expected)
    with pytest.raises(MessageError, match="where: a DiagnosticArray cut short"):
        cdr.decode_diagnostics(bytes(TS.serialize_cdr(msg, cdr.DIAGNOSTICS))[:-9], "where")


def test_the_ego_footprint_is_its_box_around_the_reference_point():
    """/ego/footprint, which a planner reads for the ego's size: the box's corners around the
    odometry's pose, in the odometry's child frame, as rosbags decodes the standard type."""
    message = msgs.TYPESTORE.deserialize_cdr(msgs.footprint_cdr(4.6, 1.9, 1_500_000_000), "geometry_msgs/msg/PolygonStamped")
    assert message.header.frame_id == cdr.CHILD_FRAME_ID and msgs.stamp_ns(message.header.stamp) == 1_500_000_000
    corners = [value for p in message.polygon.points for value in (p.x, p.y, p.z)]  # Point32: float32
    assert corners == pytest.approx([2.3, 0.95, 0, -2.3, 0.95, 0, -2.3, -0.95, 0, 2.3, -0.95, 0], abs=1e-6)


def test_a_quaternions_yaw_is_the_same_to_the_bit_from_floats_and_from_arrays():
    """Paths decode their poses' yaws as arrays, Autoware's trajectories and the objects one float at a
    time: the two must agree to the bit (numpy's arctan2 differs from libm's atan2 in the last bit for
    some inputs, by release and CPU), and a yaw must round-trip through its quaternion."""
    rng = np.random.default_rng(7)
    yaws = np.concatenate([rng.uniform(-np.pi, np.pi, 5000), [0.0, np.pi / 2, -np.pi / 2, np.pi - 1e-15]])
    q = np.array([[0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)] for yaw in yaws.tolist()])
    from_arrays = cdr.quaternion_yaw(*q.T)
    from_floats = np.array([cdr.quaternion_yaw(*row) for row in q.tolist()])
    assert from_arrays.shape == yaws.shape and np.array_equal(from_arrays, from_floats)
    np.testing.assert_allclose(from_arrays, yaws, rtol=0, atol=1e-14)
    assert cdr.quaternion_yaw(*q[:4].reshape(2, 2, 4).transpose(2, 0, 1)).shape == (2, 2)
