"""Fuzzing the CDR decoders and the lockstep parsers: whatever arrives on a topic (arbitrary bytes,
valid payloads cut short or with bits flipped, JSON of any shape), the answer is a value or one
MessageError line naming where it came from, never another exception or a hang."""

import json
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from mutations import damaged

from advperc_ros.core.perception_errors import PerceptionErrors
from advperc_ros.core.planners.base import Trajectory
from advperc_ros.exceptions import MessageError
from advperc_ros.ros import cdr, lockstep
from advperc_ros.ros import messages as msgs
from advperc_ros.ros.topics import RULE_DIAGNOSTICS

TS = cdr.TYPESTORE
# hang guard, not a timing: one decode takes well under a millisecond
FUZZ = settings(max_examples=150, deadline=2000, suppress_health_check=[HealthCheck.too_slow])
pytestmark = pytest.mark.filterwarnings("ignore::RuntimeWarning")  # yaw of a quaternion with huge entries


def objects(ids: list[int], seed: int = 0) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    out = {name: rng.uniform(0.5, 20.0, len(ids)) for name in ("x", "y", "yaw", "vx", "vy", "length", "width", "height")}
    out["ids"] = np.array(ids, dtype=np.int64)
    out["score"] = rng.uniform(0.0, 1.0, len(ids))
    return out


def big_endian(data: bytes, msgtype: str) -> bytes:
    return bytes(TS.serialize_cdr(TS.deserialize_cdr(data, msgtype), msgtype, little_endian=False))


OBJECTS = cdr.encode_objects(objects([4, 1, 9]), 1_700_000_000_123_456_789, "perception")
PATH = cdr.encode_path([1.0, 2.0, 3.0], [4.0, 5.0, 6.0], [0.0, 0.1, 0.2], [10, 20, 30], 10)
ODOMETRY = cdr.encode_odometry(1.5, -2.0, 0.7, 8.25, 123)
DIAGNOSTICS = lockstep.rule_diagnostics(77, np.array([3, -5]), np.array([1.5, np.inf]))
DECODERS = {  # name -> (decoder, a valid payload)
    "objects": (cdr.decode_objects, OBJECTS),
    "objects big endian": (cdr.decode_objects, big_endian(OBJECTS, cdr.MARKER_ARRAY)),
    "path": (cdr.decode_path, PATH),
    "path big endian": (cdr.decode_path, big_endian(PATH, cdr.PATH)),
    "odometry": (cdr.decode_odometry, ODOMETRY),
    "diagnostics": (cdr.decode_diagnostics, DIAGNOSTICS),
}


def one_line_naming(exc: Exception, *names: str) -> None:
    text = str(exc)
    assert "\n" not in text and "\r" not in text, text
    for name in names:
        assert name in text, (name, text)


@pytest.mark.parametrize("name", DECODERS)
@FUZZ
@given(data=st.data())
def test_decoders_answer_a_value_or_one_message_error(name, data):
    decode, payload = DECODERS[name]
    try:
        decode(data.draw(damaged(payload, word=4, arbitrary=True)), "where")
    except MessageError as exc:
        one_line_naming(exc, "where: ")
        assert str(exc).startswith("where: ")


@FUZZ
@given(ids=st.lists(st.integers(-2**31, 2**31 - 1), max_size=6))
def test_objects_decoder_keeps_every_id_or_names_the_repeated_one(ids):
    data = cdr.encode_objects(objects(ids), 5, "ground_truth")
    if len(set(ids)) < len(ids):
        with pytest.raises(MessageError) as caught:
            cdr.decode_objects(data, "where")
        one_line_naming(caught.value, "where: ", "field 'id'", "appears twice")
    else:
        _, got = cdr.decode_objects(data, "where")
        assert list(got["ids"]) == sorted(ids)
        assert all(len(values) == len(ids) for values in got.values())


# ----- lockstep control messages (std_msgs/String holding JSON) -----

json_values = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=6),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=6), inner, max_size=4),
    max_leaves=12,
)
ERRORS = lockstep.RolloutErrors(
    3, PerceptionErrors(np.zeros((2, 2)), np.full((2, 2), 0.5), np.zeros((2, 2)), np.array([[True, False], [False, False]])),
    np.array([1, 7]), np.array([0, 100_000_000]))
CONTROL = {  # topic -> (parser, a valid message as JSON)
    lockstep.ERRORS: (lockstep.parse_errors, json.loads(lockstep.errors_message(ERRORS).data)),
    lockstep.READY: (lockstep.parse_ready, json.loads(lockstep.ready_message(lockstep.RolloutReady(3, True, True)).data)),
    lockstep.DELIVERED: (lockstep.parse_delivered,
                         json.loads(lockstep.delivered_message(lockstep.Delivered("/tracking/objects", 5)).data)),
    lockstep.PRESENCE: (lockstep.parse_presence, json.loads(lockstep.presence_message("tracker", 42).data)),
    lockstep.DONE: (lockstep.parse_done,
                    json.loads(lockstep.done_message(lockstep.RolloutDone(3, 9, lockstep.Status.OK, "", False, "")).data)),
}


@st.composite
def control_text(draw, document: dict) -> str:
    """A valid control message with a field removed or replaced by any JSON value, any JSON
    document, or any text."""
    kind = draw(st.sampled_from(["replace", "remove", "document", "text"]))
    if kind == "text":
        return draw(st.text(max_size=40))
    if kind == "document":
        return json.dumps(draw(json_values))
    document = dict(document)
    key = draw(st.sampled_from(sorted(document)))
    if kind == "remove":
        del document[key]
    else:
        document[key] = draw(json_values)
    return json.dumps(document)


def check_control(parsed, topic: str) -> None:
    """What a parser returns when it accepts: the types and shapes the nodes rely on."""
    if topic == lockstep.ERRORS:
        shape = (len(parsed.stamps_ns), len(parsed.agent_ids))
        assert parsed.errors.shape == shape and parsed.errors.fn.dtype == bool
        for values in (parsed.errors.dx, parsed.errors.dy, parsed.errors.dyaw):
            assert values.shape == shape and np.isfinite(values).all()
    elif topic == lockstep.DONE:
        assert parsed.status in (lockstep.Status.OK, lockstep.Status.INCONCLUSIVE) and isinstance(parsed.timeout, bool)
        assert isinstance(parsed.gone, str)
    elif topic == lockstep.PRESENCE:
        assert isinstance(parsed[0], str) and type(parsed[1]) is int
    elif topic == lockstep.DELIVERED:
        assert isinstance(parsed.topic, str) and type(parsed.stamp_ns) is int
    else:
        assert type(parsed.rollout) is int and type(parsed.ahead) is bool and type(parsed.confirmed) is bool


@pytest.mark.parametrize("topic", CONTROL)
@FUZZ
@given(data=st.data())
def test_control_parsers_answer_a_value_or_one_message_error(topic, data):
    parse, document = CONTROL[topic]
    text = data.draw(control_text(document))
    try:
        parsed = parse(msgs.string(text))
    except MessageError as exc:
        one_line_naming(exc, topic)
    else:
        check_control(parsed, topic)


@pytest.mark.parametrize("topic", CONTROL)
def test_control_parsers_read_what_the_nodes_write(topic):
    parse, document = CONTROL[topic]
    check_control(parse(msgs.string(json.dumps(document))), topic)


def test_errors_message_round_trips():
    back = lockstep.parse_errors(lockstep.errors_message(ERRORS))
    assert back.rollout == 3 and back.errors.equals(ERRORS.errors)
    assert list(back.agent_ids) == [1, 7] and list(back.stamps_ns) == [0, 100_000_000]


@pytest.mark.parametrize("field, value, words", [
    ("fn", [[1, 0], [0, 0]], ["'fn'", "booleans"]),  # 1 is no bool
    ("dx", [[0.0, math.nan], [0.0, 0.0]], ["'dx'", "finite"]),
    ("dy", [[0.0], [0.0]], ["'dy'", "2x2"]),
    ("stamps_ns", [0, 1.5], ["'stamps_ns'", "integers"]),
    ("rollout", "3", ["'rollout'", "int"]),
])
def test_errors_message_names_the_wrong_field(field, value, words):
    document = dict(CONTROL[lockstep.ERRORS][1], **{field: value})
    with pytest.raises(MessageError) as caught:
        lockstep.parse_errors(msgs.string(json.dumps(document)))
    one_line_naming(caught.value, lockstep.ERRORS, *words)


def diagnostics_of(statuses: list[cdr.Status]) -> bytes:
    T = TS.types
    msg = T["diagnostic_msgs/msg/DiagnosticArray"](header=msgs.header(77), status=[
        T["diagnostic_msgs/msg/DiagnosticStatus"](
            level=s.level, name=s.name, message=s.message, hardware_id=s.hardware_id,
            values=[T["diagnostic_msgs/msg/KeyValue"](key=k, value=v) for k, v in s.values.items()])
        for s in statuses])
    return bytes(TS.serialize_cdr(msg, cdr.DIAGNOSTICS))


words = st.text(st.characters(exclude_categories=["Cs"]), max_size=8)  # CDR strings are UTF-8: no lone surrogates
keys = st.sampled_from([lockstep.MIN_KEY, "agent 3", "agent -12", "agent x", "agent  3", "agent 3_0", "note"]) | words
texts = st.sampled_from(["1.5", "-0.25", "inf", "-inf", "nan", "", "x", "1e999", repr(2.0**-1074)]) | words
statuses = st.builds(cdr.Status, st.integers(0, 127), st.sampled_from([lockstep.RULE_STATUS, "other"]) | words,
                     words, words, st.dictionaries(keys, texts, max_size=4))


@FUZZ
@given(statuses=st.lists(statuses, max_size=3))
def test_rule_diagnostics_parser_answers_distances_or_one_message_error(statuses):
    try:
        stamp, minimum, per_agent = lockstep.parse_rule_diagnostics(diagnostics_of(statuses))
    except MessageError as exc:
        one_line_naming(exc, RULE_DIAGNOSTICS)
    else:
        assert stamp == 77 and not math.isnan(minimum)
        assert all(type(agent) is int and not math.isnan(d) for agent, d in per_agent.items())


@FUZZ
@given(data=st.data())
def test_plan_parser_answers_a_trajectory_or_one_message_error(data):
    try:
        _, plan = lockstep.plan_from_cdr(data.draw(damaged(PATH, word=4, arbitrary=True)), 0, "where")
    except MessageError as exc:
        one_line_naming(exc, "where: ")
    else:
        assert isinstance(plan, Trajectory) and len(plan.t) == len(plan.x) == len(plan.y) == len(plan.yaw)
