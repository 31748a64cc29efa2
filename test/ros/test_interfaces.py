"""Interface profiles: each stack's types convert to and from the graph's boxes and plans as
advperc_ros/ros/interfaces says (exactly where the types allow), refuse bad messages in one line,
and, with ROS 2 sourced, are byte for byte and hash for hash the upstream packages' own types."""

import json
import math
from pathlib import Path

import numpy as np
import pytest

from conftest import REPO, need_ros

from advperc_ros.core.boxes import BOX_FIELDS
from advperc_ros.core.ego_motion import follow_plan
from advperc_ros.core.planners.base import EMPTY_PLAN, Trajectory
from advperc_ros.exceptions import MessageError, PluginError
from advperc_ros.params import SCHEMA
from advperc_ros.ros import cdr
from advperc_ros.ros import messages as msgs
from advperc_ros.ros.interfaces import autoware
from advperc_ros.ros.interfaces.registry import BUNDLED, load_profile

T = cdr.TYPESTORE.types
STAMP = 1_700_000_123_456_789_012


def boxes(n: int = 5, seed: int = 0) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    objects = {name: rng.uniform(-50, 50, n) for name in ("x", "y", "vx", "vy")}
    objects.update(yaw=rng.uniform(-math.pi, math.pi, n), length=rng.uniform(3, 6, n), width=rng.uniform(1.5, 2.5, n),
                   height=rng.uniform(1.2, 2.0, n), score=rng.uniform(0.1, 1.0, n))
    objects["ids"] = np.sort(rng.choice(np.arange(-1000, 1000), n, replace=False)).astype(np.int64)
    return objects


def plan(seed: int = 0) -> Trajectory:
    rng = np.random.default_rng(seed)
    t = 12.3 + np.arange(40) * 0.1 + rng.uniform(0, 1e-3, 40)
    return Trajectory(t=t, x=np.cumsum(rng.uniform(0, 2, 40)), y=rng.uniform(-1, 1, 40), yaw=rng.uniform(-0.2, 0.2, 40))


@pytest.mark.parametrize("name", sorted(BUNDLED))
@pytest.mark.parametrize("layer", ["detections", "tracks"])
def test_boxes_round_trip_as_each_profile_says(name, layer):
    """Positions, headings and sizes exactly (to 1e-12 of a quaternion's round trip); velocity where the
    type has one; ids where it carries them."""
    objects = boxes()
    channel = getattr(load_profile(name), layer)
    stamp, back = channel.decode(channel.encode(objects, STAMP, "perception"), channel.topic)
    assert stamp == STAMP
    has_ids = channel.msgtype != autoware.DETECTED
    order = np.arange(len(objects["ids"])) if has_ids else np.argsort(objects["ids"])  # DetectedObjects: message order
    if has_ids:
        assert np.array_equal(back["ids"], objects["ids"])
    else:
        assert np.array_equal(back["ids"], np.arange(len(objects["ids"])))
    for field in ("x", "y", "yaw", "length", "width", "height"):
        np.testing.assert_allclose(back[field], objects[field][order], rtol=0, atol=1e-12, err_msg=field)
    for field in ("vx", "vy"):
        expected = objects[field][order] if channel.carries_velocity else np.zeros(len(order))
        np.testing.assert_allclose(back[field], expected, rtol=0, atol=1e-12, err_msg=field)


def test_autoware_twist_is_in_the_object_frame_and_ids_are_uuids():
    """An object heading north (yaw pi/2) moving north at 10 m/s has twist.linear.x = 10 (forward), not
    its map-frame vx; its UUID's first 8 bytes are its id."""
    objects = {name: np.array([0.0]) for name in BOX_FIELDS}
    objects.update(ids=np.array([-3], dtype=np.int64), yaw=np.array([math.pi / 2]), vy=np.array([10.0]),
                   length=np.array([4.0]), width=np.array([2.0]), height=np.array([1.5]), score=np.array([math.nan]))
    msg = cdr.TYPESTORE.deserialize_cdr(autoware.encode_predicted(objects, STAMP), autoware.PREDICTED)
    twist = msg.objects[0].kinematics.initial_twist_with_covariance.twist.linear
    assert twist.x == pytest.approx(10.0, abs=1e-12) and twist.y == pytest.approx(0.0, abs=1e-12)
    uuid = bytes(msg.objects[0].object_id.uuid)
    assert int.from_bytes(uuid[:8], "little", signed=True) == -3 and uuid[8:] == bytes(8)
    path = msg.objects[0].kinematics.predicted_paths[0]
    assert path.path[-1].position.y == pytest.approx(10.0 * autoware.PREDICTION_HORIZON)  # constant velocity
    assert msg.objects[0].classification[0].label == 1  # CAR


@pytest.mark.parametrize("name", sorted(BUNDLED))
def test_plans_round_trip_to_the_nanosecond(name):
    """Every profile's plan type times its points as a stamped Path does: the same times, bit for bit."""
    layer = load_profile(name).plan
    original = plan()
    first = STAMP - 12_300_000_000
    stamp, back = layer.decode(layer.encode(original, STAMP), first, (0.0, 0.0), layer.topic)
    reference = msgs.trajectory_cdr(original, STAMP)
    _, path = load_profile("advperc").plan.decode(reference, first, (0.0, 0.0), "path")
    assert stamp == STAMP
    assert np.array_equal(back.t, path.t)
    for field in ("x", "y", "yaw"):
        assert np.array_equal(getattr(back, field), getattr(path, field)), field
    _, empty = layer.decode(layer.encode(EMPTY_PLAN, STAMP), first, (0.0, 0.0), layer.topic)
    assert len(empty.t) == 0


def _trajectory(xs, speeds) -> bytes:
    points = [T["autoware_planning_msgs/msg/TrajectoryPoint"](
        time_from_start=T["builtin_interfaces/msg/Duration"](sec=0, nanosec=0), pose=msgs.pose(x, 0.0, 0.0),
        longitudinal_velocity_mps=float(v), lateral_velocity_mps=0.0, acceleration_mps2=0.0, heading_rate_rps=0.0,
        front_wheel_angle_rad=0.0, rear_wheel_angle_rad=0.0) for x, v in zip(xs, speeds)]
    msg = T[autoware.TRAJECTORY](header=msgs.header(STAMP), points=points)
    return bytes(cdr.TYPESTORE.serialize_cdr(msg, autoware.TRAJECTORY))


def test_an_autoware_trajectory_without_times_is_timed_from_the_ego_and_its_speeds():
    """Sampled by distance (1 m), starting 3 m behind the ego, at 10 m/s: the plan starts at the ego's
    foot on it (x = 0.2), each point x is reached (x - 0.2 m) / (10 m/s) after the plan's time, and the
    points behind are dropped."""
    xs = np.arange(-3.0, 30.0)
    first = STAMP - 5_000_000_000
    _, timed = autoware.decode_trajectory(_trajectory(xs, np.full(len(xs), 10.0)), first, (0.2, 1.0), "t")
    assert timed.x[0] == pytest.approx(0.2) and timed.x[1] == 1.0 and len(timed.x) == 30
    np.testing.assert_allclose(timed.t, 5.0 + (timed.x - 0.2) / 10.0, rtol=0, atol=1e-12)


def test_a_trajectory_timed_from_speeds_stops_where_the_speed_reaches_zero():
    """Speeds 4 m/s falling to 0 at x = 5: segments take length over mean speed; the ego stops at x = 5
    and waits there (the stop point held for STOP_HOLD)."""
    xs = np.arange(0.0, 10.0)
    speeds = np.clip(4.0 - 0.8 * xs, 0.0, None)  # 0 from x = 5 on
    _, timed = autoware.decode_trajectory(_trajectory(xs, speeds), STAMP, (0.0, 0.0), "t")
    sent = speeds.astype(np.float32).astype(float)  # longitudinal_velocity_mps is a float32
    means = (sent[:-1] + sent[1:]) / 2
    assert len(timed.t) == 7  # points 0..5: the segment 4 -> 5 (mean 0.4) is driven, 5 -> 6 (mean 0) is not
    np.testing.assert_allclose(timed.t[:6], np.concatenate(([0.0], np.cumsum(1.0 / means[:5]))), rtol=0, atol=1e-12)
    assert timed.x[-1] == timed.x[-2] == 5.0 and timed.t[-1] == timed.t[-2] + autoware.STOP_HOLD
    assert follow_plan(timed, timed.t[5] + 2.0).x == 5.0


@pytest.mark.parametrize("name", sorted(BUNDLED))
def test_a_payload_of_another_type_is_one_line_naming_the_topic(name):
    profile = load_profile(name)
    wrong = cdr.encode_clock(STAMP)
    for layer in (profile.detections, profile.tracks):
        with pytest.raises(MessageError, match=f"^{layer.topic}: "):
            layer.decode(wrong, layer.topic)
    with pytest.raises(MessageError, match=f"^{profile.plan.topic}: "):
        profile.plan.decode(wrong, 0, (0.0, 0.0), profile.plan.topic)


def test_autoware_shapes_read_back_as_boxes_and_a_bad_one_is_refused():
    objects = boxes(1)
    msg = cdr.TYPESTORE.deserialize_cdr(autoware.encode_tracked(objects, STAMP), autoware.TRACKED)
    shape = msg.objects[0].shape
    square = [T["geometry_msgs/msg/Point32"](x=x, y=y, z=0.0) for x, y in ((-2, -1), (2, -1), (2, 1), (-2, 1))]
    for kind, footprint, size in ((1, [], (3.0, 3.0)), (2, square, (4.0, 2.0))):
        changed = msg.objects[0].__class__(**{**msg.objects[0].__dict__, "shape": shape.__class__(
            type=kind, footprint=T["geometry_msgs/msg/Polygon"](points=footprint),
            dimensions=T["geometry_msgs/msg/Vector3"](x=3.0, y=7.0, z=1.5))})
        data = cdr.TYPESTORE.serialize_cdr(msg.__class__(header=msg.header, objects=[changed]), autoware.TRACKED)
        _, back = autoware.decode_tracked(data, "tracks")
        assert (back["length"][0], back["width"][0]) == size
    for kind, footprint, says in ((2, [], "field 'shape.footprint'"), (7, [], "field 'shape.type' is 7")):
        changed = msg.objects[0].__class__(**{**msg.objects[0].__dict__, "shape": shape.__class__(
            type=kind, footprint=T["geometry_msgs/msg/Polygon"](points=footprint), dimensions=shape.dimensions)})
        data = cdr.TYPESTORE.serialize_cdr(msg.__class__(header=msg.header, objects=[changed]), autoware.TRACKED)
        with pytest.raises(MessageError, match=f"^tracks, object 0: {says}"):
            autoware.decode_tracked(data, "tracks")


def test_two_objects_with_one_uuid_are_refused():
    objects = boxes(2)
    objects["ids"][:] = 7
    with pytest.raises(MessageError, match="field 'id': object 7 appears twice"):
        autoware.decode_predicted(autoware.encode_predicted(objects, STAMP), "objects")


def test_the_schema_offers_exactly_the_registered_profiles():
    assert SCHEMA["graph.interface"].choices == tuple(BUNDLED)
    with pytest.raises(PluginError, match="unknown interface 'ros1' \\(interfaces: advperc, autoware"):
        load_profile("ros1")


def _share(package: str) -> Path:
    from ament_index_python.packages import get_package_share_directory

    return Path(get_package_share_directory(package))


DEFINITIONS = {msgtype: text for name in BUNDLED for msgtype, text in load_profile(name).message_types.items()}
"""Every stack's own message type a bundled profile carries."""


@pytest.mark.parametrize("msgtype", sorted(DEFINITIONS))
def test_stack_types_are_the_upstream_packages_own(msgtype):
    """With ROS 2 sourced (and the kit's message overlay): the RIHS01 hash rosbags computes from our
    definition is the one rosidl generated for the upstream package, and rclpy's serialisation of a
    message read from our bytes gives our bytes back."""
    need_ros()
    package, _, name = msgtype.split("/")
    try:
        module = need_ros(f"{package}.msg")
    except pytest.skip.Exception:
        raise
    description = json.loads((_share(package) / "msg" / f"{name}.json").read_text())
    assert cdr.TYPESTORE.hash_rihs01(msgtype) == description["type_hashes"][0]["hash_string"]
    from rclpy.serialization import deserialize_message, serialize_message

    examples = {autoware.PREDICTED: autoware.encode_predicted(boxes(), STAMP),
                autoware.TRACKED: autoware.encode_tracked(boxes(), STAMP),
                autoware.DETECTED: autoware.encode_detected(boxes(), STAMP),
                autoware.TRAJECTORY: autoware.encode_trajectory(plan(), STAMP),
                "vision_msgs/msg/Detection3DArray": load_profile("vision_msgs").detections.encode(boxes(), STAMP, "")}
    if msgtype in examples:
        data = examples[msgtype]
        assert serialize_message(deserialize_message(data, getattr(module, name))) == data


def test_an_ego_a_hair_from_a_sample_point_still_gets_a_speed():
    """The ego's foot 1e-12 m before a sample point made a segment of 1e-13 s, and the speed read from
    the plan 0/0: nan odometry (seen with the Autoware example). Such points are one point."""
    xs = np.arange(-3.0, 30.0)
    _, timed = autoware.decode_trajectory(_trajectory(xs, np.full(len(xs), 10.0)), STAMP, (3.0 - 1e-12, 0.0), "t")
    assert np.all(np.diff(timed.t) >= 1e-4)
    assert follow_plan(timed, timed.t[0] + 0.1).v == pytest.approx(10.0)


def test_nan_poses_are_reported_as_nan_poses_not_as_the_times_they_make():
    """A distance-sampled Autoware Trajectory is timed from its poses' spacing, so a NaN pose made NaN times,
    and the rollout said "plan timestamps must be finite": the poses are the cause, and are named."""
    from advperc_ros.exceptions import PlanError

    xs = np.arange(0.0, 30.0)
    xs[5] = np.nan
    _, timed = autoware.decode_trajectory(_trajectory(xs, np.full(len(xs), 10.0)), STAMP, (0.0, 0.0), "t")
    with pytest.raises(PlanError, match=r"plan holds non-finite poses \(pose \d+ of \d+: x nan"):
        follow_plan(timed, timed.t[0] + 0.1)
    # timed by its stamps: the same cause, the same words, the pose named
    with pytest.raises(PlanError, match=r"non-finite poses \(pose 1 of 3: x inf, y 0.0, yaw 0.0\)"):
        follow_plan(Trajectory(t=np.arange(3.0), x=np.array([0.0, np.inf, 2.0]), y=np.zeros(3), yaw=np.zeros(3)), 0.5)


def test_a_plan_whose_poses_are_a_rounding_error_apart_is_refused_not_followed_at_nan():
    from advperc_ros.exceptions import PlanError

    t = np.array([3.0, np.nextafter(3.0, 4.0), 3.1])  # one ulp apart
    with pytest.raises(PlanError, match="too close in time"):
        follow_plan(Trajectory(t=t, x=np.array([0.0, 0.0, 1.0]), y=np.zeros(3), yaw=np.zeros(3)), 3.0)


def test_the_docs_profile_table_is_the_registry_s():
    """docs/stacks.md's table lists every profile's topics and types as the code has them."""
    page = (REPO / "docs" / "stacks.md").read_text()
    table = page.split("<!-- profiles table")[1].split("<!-- end of profiles table")[0]
    rows = {}
    for line in table.splitlines()[3:]:
        cells = [cell.strip() for cell in line.strip("|").split("|")]
        rows[cells[0].split()[0].strip("`")] = [cell.replace("`", "").split() for cell in cells[1:]]
    assert sorted(rows) == sorted(BUNDLED)
    for name, (detections, tracks, plan, ego, extra) in rows.items():
        profile = load_profile(name)
        assert extra == [topic for topic in (profile.acceleration_topic, profile.transforms_topic) if topic] or ["-"], name
        assert detections == [profile.detections.topic, profile.detections.msgtype], name
        assert tracks == [profile.tracks.topic, profile.tracks.msgtype], name
        assert plan == [profile.plan.topic, profile.plan.msgtype], name
        assert ego == [profile.ego_topic], name


class _Recorder:
    """A transport that keeps what is published per topic and hands out the subscriptions' callbacks."""

    def __init__(self) -> None:
        self.published: dict[str, list] = {}
        self.callbacks: dict[str, object] = {}

    def publisher(self, topic, msgtype, latched=False):
        sent = self.published.setdefault(topic, [])
        return type("Publisher", (), {"publish": staticmethod(sent.append)})()

    def subscriber(self, topic, msgtype, latched=False, callback=None, raw=False, wake=True):
        self.callbacks[topic] = callback

    def publisher_count(self, topic):
        return None  # as a transport that cannot tell


def _three_frames(profile_name: str, transport=None, said=None, ahead=False):
    """The player of idm_lane_following under a profile, through three frames whose plans speed the ego up,
    hold and brake; (its transport, the frame stamps). `said` keeps its warnings; `ahead`: the ready
    message lets it run the ground truth a frame ahead."""
    from advperc_ros.nodes.scenario_player import ScenarioPlayer
    from advperc_ros.ros.lockstep import RolloutReady, ready_message, rule_diagnostics
    from advperc_ros.ros.topics import READY, RULE_DIAGNOSTICS

    bag = REPO / "bags" / "idm_lane_following"
    transport = transport or _Recorder()
    profile = load_profile(profile_name)
    warn = said.append if said is not None else print
    logger = type("Log", (), {"info": print, "warning": staticmethod(warn)})()
    player = ScenarioPlayer(transport, bag, True, 10.0, profile, False, logger, (4.6, 1.9))
    stamps = [int(s) for s in player.scenario.stamps_ns]
    start = player.scenario.ego_start
    transport.callbacks[READY](ready_message(RolloutReady(1, ahead)))
    for k, speed in enumerate([start.v + 0.5, start.v + 0.5, start.v - 1.0]):
        t = np.array([0.0, 0.1, 0.2, 2.0]) + (stamps[k] - stamps[0]) * 1e-9
        x = start.x + speed * (t - t[0]) + k
        plan = Trajectory(t=t, x=x, y=np.full(4, start.y), yaw=np.zeros(4))
        transport.callbacks[RULE_DIAGNOSTICS](rule_diagnostics(stamps[k], np.array([1]), np.array([9.0])))
        transport.callbacks[profile.plan.topic](profile.plan.encode(plan, stamps[k]))
    return transport, stamps


class _Ordered(_Recorder):
    """A _Recorder that also keeps the order of everything published, across topics."""

    def __init__(self) -> None:
        super().__init__()
        self.order: list[str] = []

    def publisher(self, topic, msgtype, latched=False):
        sent = self.published.setdefault(topic, [])

        def publish(data):
            sent.append(data)
            self.order.append(topic)
        return type("Publisher", (), {"publish": staticmethod(publish)})()


def test_ahead_the_player_publishes_the_next_frame_s_ground_truth_after_the_ego():
    """Told `ahead`, the player sends frame k+1's ground truth with frame k, after the odometry the
    planner waits for; the ego it drives is the same as in turn, frame for frame."""
    from advperc_ros.ros import cdr

    in_turn, stamps = _three_frames("advperc")
    ahead, _ = _three_frames("advperc", transport=_Ordered(), ahead=True)

    def truth_stamps(transport):
        return [cdr.decode_objects(data, "test")[0] for data in transport.published["/ground_truth/objects"]]
    assert truth_stamps(in_turn) == stamps[:4]  # frames 0-3: three answered, the fourth published
    assert truth_stamps(ahead) == stamps[:5]  # and frame 4's, ahead
    assert ahead.published["/ego/odometry"] == in_turn.published["/ego/odometry"]
    per_frame = [topic for topic in ahead.order if topic in ("/ground_truth/objects", "/ego/odometry")]
    assert per_frame == ["/ground_truth/objects", "/ego/odometry", "/ground_truth/objects"] + \
        ["/ego/odometry", "/ground_truth/objects"] * 3


@pytest.mark.parametrize("clock, says", [
    ("wall", "the wall clock's time; is use_sim_time set on the node publishing them?"),
    ("own", "a plan must carry the stamp of the inputs it answers"),
])
def test_a_frame_whose_plans_came_under_another_clock_names_the_stamps_they_came_with(clock, says):
    """Issue 51: a planner that forgot use_sim_time publishes plans stamped at wall time, which the player
    ignores; the frame's timeout said "no plan stamped ... (a node is dead or silent)", though plans came."""
    import time

    from advperc_ros.nodes.scenario_player import ScenarioPlayer
    from advperc_ros.ros.lockstep import RolloutReady, parse_done, ready_message, rule_diagnostics
    from advperc_ros.ros.topics import DONE, READY, RULE_DIAGNOSTICS

    transport, said = _Recorder(), []
    profile = load_profile("autoware")
    logger = type("Log", (), {"info": print, "warning": staticmethod(said.append)})()
    player = ScenarioPlayer(transport, REPO / "bags" / "idm_lane_following", True, 0.5, profile, False, logger,
                            (4.6, 1.9))
    stamps = [int(s) for s in player.scenario.stamps_ns]
    stray = time.time_ns() if clock == "wall" else stamps[0] + 7  # a stamp of no frame, nor of the wall clock
    start = player.scenario.ego_start
    plan = Trajectory(t=np.array([0.0, 0.5, 1.0]) + stray * 1e-9, x=start.x + np.array([0.0, 1.0, 2.0]),
                      y=np.full(3, start.y), yaw=np.zeros(3))
    transport.callbacks[READY](ready_message(RolloutReady(1, False)))
    transport.callbacks[RULE_DIAGNOSTICS](rule_diagnostics(stamps[0], np.array([1]), np.array([9.0])))
    transport.callbacks[profile.plan.topic](profile.plan.encode(plan, stray))
    time.sleep(0.6)
    player.poll()
    done = parse_done(transport.published[DONE][-1])
    assert done.timeout and done.reason.startswith(f"frame 0: no plan stamped {stamps[0]} within 0.5 s (plans arrive "
                                                   f"stamped {stray} ({stray * 1e-9:.1f} s)"), done.reason
    assert f"the clock is at {stamps[0] * 1e-9:.1f} s" in done.reason and says in done.reason
    assert "dead or silent" not in done.reason and said[-1].endswith(done.reason)


def test_under_autoware_the_player_publishes_the_ego_s_acceleration_as_its_speed_changes():
    """/localization/acceleration, which Autoware's planners read: the change of the ego's speed over
    each frame, 0 at the start, stamped with the frame, in the odometry's child frame."""
    transport, stamps = _three_frames("autoware")
    sent = [msgs.TYPESTORE.deserialize_cdr(data, msgs.ACCELERATION) for data in transport.published[autoware.ACCELERATION_TOPIC]]
    speeds = [msgs.ego_from_cdr(data, "odometry")[1].v for data in transport.published["/ego/odometry"]]
    assert [msgs.stamp_ns(m.header.stamp) for m in sent] == stamps[:len(sent)] and len(sent) == len(speeds) >= 3
    expected = [0.0] + [(b - a) / ((t1 - t0) * 1e-9) for a, b, t0, t1 in zip(speeds, speeds[1:], stamps, stamps[1:])]
    assert [m.accel.accel.linear.x for m in sent] == pytest.approx(expected, abs=1e-12)
    assert all(m.header.frame_id == cdr.CHILD_FRAME_ID for m in sent) and any(abs(a) > 0.1 for a in expected)
    quiet, _ = _three_frames("advperc")  # our own profile has no acceleration topic, nor /tf
    assert autoware.ACCELERATION_TOPIC not in quiet.published and autoware.TRANSFORMS_TOPIC not in quiet.published


def test_under_autoware_the_player_publishes_map_to_base_link_on_tf_where_the_odometry_puts_the_ego():
    """/tf, through which Autoware's nodes look up the ego: per frame one transform map -> base_link,
    stamped with the frame, at the odometry's pose to the bit (the centre of the ego's box)."""
    transport, stamps = _three_frames("autoware")
    sent = [msgs.TYPESTORE.deserialize_cdr(data, msgs.TRANSFORMS) for data in transport.published[autoware.TRANSFORMS_TOPIC]]
    odometry = [msgs.TYPESTORE.deserialize_cdr(data, msgs.ODOMETRY) for data in transport.published["/ego/odometry"]]
    assert len(sent) == len(odometry) >= 3
    for message, ego, stamp in zip(sent, odometry, stamps):
        (transform,) = message.transforms
        assert msgs.stamp_ns(transform.header.stamp) == stamp == msgs.stamp_ns(ego.header.stamp)
        assert (transform.header.frame_id, transform.child_frame_id) == (cdr.FRAME_ID, cdr.CHILD_FRAME_ID)
        assert ego.child_frame_id == cdr.CHILD_FRAME_ID
        pose, moved = ego.pose.pose, transform.transform
        assert (moved.translation.x, moved.translation.y, moved.translation.z) == (pose.position.x, pose.position.y, 0.0)
        rotation, orientation = moved.rotation, pose.orientation
        assert (rotation.x, rotation.y, rotation.z, rotation.w) == (orientation.x, orientation.y, orientation.z, orientation.w)


def test_a_ros_without_tf2_msgs_for_python_leaves_tf_out_and_says_so_once():
    """rclpy makes an endpoint only from a type's Python package, and a minimal ROS 2 (this kit) has none
    for tf2_msgs: the player then publishes everything else, and says once which topic it leaves out."""
    from advperc_ros.exceptions import MessageTypeMissing

    class WithoutTf(_Recorder):
        def publisher(self, topic, msgtype, latched=False):
            if msgtype == msgs.TRANSFORMS:
                raise MessageTypeMissing(f"{msgtype}: this ROS 2 has no Python package 'tf2_msgs'")
            return super().publisher(topic, msgtype, latched)

    said: list[str] = []
    transport, _ = _three_frames("autoware", WithoutTf(), said)
    assert said == ["/tf is not published: tf2_msgs/msg/TFMessage: this ROS 2 has no Python package 'tf2_msgs'"]
    assert autoware.TRANSFORMS_TOPIC not in transport.published
    assert len(transport.published[autoware.ACCELERATION_TOPIC]) == len(transport.published["/ego/odometry"]) >= 3


@pytest.mark.parametrize("publishers, gone", [(0, True), (1, False), (None, False)])
def test_a_frame_whose_plans_have_no_publisher_left_says_so_and_marks_the_node_gone(publishers, gone):
    """Issue 51 over bare DDS, which names no nodes: a planner started by hand that died left each rollout to
    time out; the player's reader of the plans matching no publisher is how the orchestrator learns it is gone
    (`gone` in /attack/done), where a transport that cannot tell (None) or a live publisher changes nothing."""
    import time

    from advperc_ros.nodes.scenario_player import ScenarioPlayer
    from advperc_ros.ros.lockstep import RolloutReady, parse_done, ready_message
    from advperc_ros.ros.topics import DONE, READY

    transport = _Recorder()
    transport.publisher_count = lambda topic: publishers if topic == "/planning/trajectory" else 1
    logger = type("Log", (), {"info": print, "warning": staticmethod(print)})()
    player = ScenarioPlayer(transport, REPO / "bags" / "idm_lane_following", True, 0.2, load_profile("advperc"), False,
                            logger, (4.6, 1.9))
    transport.callbacks[READY](ready_message(RolloutReady(1, False)))
    time.sleep(0.3)
    player.poll()
    done = parse_done(transport.published[DONE][-1])
    said = "no node publishes plans on /planning/trajectory (never started, ended, or left the DDS domain)"
    assert done.timeout and (done.gone == said) is gone and (said in done.reason) is gone, done
    assert done.gone or "(a node is dead or silent)" in done.reason
