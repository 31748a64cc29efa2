"""The clock drive delivers a frame before its clock (issue 51): the player advances /clock to t_k only
once every reader has acknowledged the ego's inputs and, with our tracker, once the tracker has said that
every reader holds the frame's tracks; a reader that never acknowledges makes the rollout inconclusive.
A timer node that plans on each tick with whatever it holds then plans on frame k (test_ros2.py runs
one under load). Here the nodes' logic runs on a recording transport, no DDS."""

from pathlib import Path

import numpy as np
import pytest

from advperc_ros.core.boxes import BOX_FIELDS
from advperc_ros.nodes import tracker as tracker_node
from advperc_ros.nodes.scenario_player import ScenarioPlayer
from advperc_ros.params import SCHEMA
from advperc_ros.ros import cdr
from advperc_ros.ros.interfaces.registry import load_profile
from advperc_ros.ros.lockstep import (
    Delivered,
    RolloutReady,
    parse_delivered,
    parse_done,
    parse_ready,
    ready_message,
)
from advperc_ros.ros.lockstep import delivered_message as delivered
from advperc_ros.ros.topics import CLOCK, DELIVERED, DONE, ODOMETRY, READY, TRACKING

REPO = Path(__file__).resolve().parents[2]
BAG = REPO / "bags" / "idm_lane_following"


class _Acknowledging:
    """A transport keeping, in one list, every publish and every wait for acknowledgements in the order
    they happen; each publisher's waits answer `acknowledged` (its topic -> bool, True when absent)."""

    def __init__(self, acknowledged: dict[str, bool] | None = None) -> None:
        self.events: list[tuple[str, str, object]] = []
        self.callbacks: dict[str, object] = {}
        self.acknowledged = acknowledged or {}

    def publisher(self, topic, msgtype, latched=False):
        events, acknowledged = self.events, self.acknowledged

        class Publisher:
            def publish(self, data):
                events.append(("publish", topic, data))

            def wait_for_acks(self, timeout):
                events.append(("acks", topic, timeout))
                return acknowledged.get(topic, True)
        return Publisher()

    def subscriber(self, topic, msgtype, latched=False, callback=None, raw=False, wake=True):
        self.callbacks[topic] = callback

    def since(self, mark: int) -> list[tuple[str, str]]:
        return [(kind, topic) for kind, topic, _ in self.events[mark:]]


def _player(transport, confirmed: bool, timeout: float = 10.0):
    said: list[str] = []
    logger = type("Log", (), {"info": print, "warning": staticmethod(said.append)})()
    player = ScenarioPlayer(transport, BAG, True, timeout, load_profile("advperc"), True, logger, (4.6, 1.9))
    transport.callbacks[READY](ready_message(RolloutReady(1, False, confirmed)))
    return player, [int(stamp) for stamp in player.scenario.stamps_ns], said


def _no_boxes(stamp: int, kind: str) -> bytes:
    """A frame of no objects, as our detections and tracks carry it."""
    return cdr.encode_objects({"ids": np.zeros(0, np.int64), **{name: np.zeros(0) for name in BOX_FIELDS}}, stamp, kind)


def _clock_stamps(transport) -> list[bytes]:
    return [data for kind, topic, data in transport.events if kind == "publish" and topic == CLOCK]


def test_with_our_tracker_the_clock_waits_for_its_word_and_the_ego_s_acknowledgements():
    transport = _Acknowledging()
    _, stamps, _ = _player(transport, confirmed=True)
    before = _clock_stamps(transport)
    assert before == [cdr.encode_clock(stamps[-1])]  # the rollout's start: the step to t_0 is a jump back
    transport.callbacks[TRACKING](_no_boxes(stamps[0], "tracking"))
    assert _clock_stamps(transport) == before  # the tracks reached the player: not yet every reader
    transport.callbacks[DELIVERED](delivered(Delivered(TRACKING, stamps[1])))  # another frame's word
    transport.callbacks[DELIVERED](delivered(Delivered("/elsewhere", stamps[0])))  # another topic's
    assert _clock_stamps(transport) == before
    mark = len(transport.events)
    transport.callbacks[DELIVERED](delivered(Delivered(TRACKING, stamps[0])))
    assert transport.since(mark) == [("acks", ODOMETRY), ("publish", CLOCK)]  # the ego's inputs first, then the clock
    assert _clock_stamps(transport)[-1] == cdr.encode_clock(stamps[0])


def test_with_a_team_s_tracker_the_clock_moves_once_its_tracks_reach_the_player():
    """A team's tracker confirms nothing: the player goes by its tracks, still after the ego's acknowledgements."""
    transport = _Acknowledging()
    _, stamps, _ = _player(transport, confirmed=False)
    transport.callbacks[DELIVERED](delivered(Delivered(TRACKING, stamps[0])))  # not this rollout's way
    assert _clock_stamps(transport) == [cdr.encode_clock(stamps[-1])]
    mark = len(transport.events)
    transport.callbacks[TRACKING](_no_boxes(stamps[0], "tracking"))
    assert transport.since(mark) == [("acks", ODOMETRY), ("publish", CLOCK)]


def test_odometry_no_reader_acknowledges_makes_the_rollout_inconclusive_and_keeps_the_clock():
    transport = _Acknowledging({ODOMETRY: False})
    _, stamps, said = _player(transport, confirmed=True, timeout=0.25)
    transport.callbacks[DELIVERED](delivered(Delivered(TRACKING, stamps[0])))
    assert _clock_stamps(transport) == [cdr.encode_clock(stamps[-1])]
    (done,) = [parse_done(data) for kind, topic, data in transport.events if kind == "publish" and topic == DONE]
    assert done.status == "inconclusive" and done.timeout
    assert done.reason == (f"frame 0: the ego's inputs stamped {stamps[0]} were not acknowledged by every reader "
                           "within 0.25 s (a node is hung)")
    assert said[-1].endswith(done.reason)


def _tracker(transport, drive: str):
    values = {name: SCHEMA[name].default for name in tracker_node.SPEC.params}
    values["graph.drive"] = drive
    log: list[str] = []
    logger = type("Log", (), {"info": print, "warning": staticmethod(log.append), "error": staticmethod(log.append)})()
    return tracker_node.SPEC.build(transport, values, {}, logger), log


@pytest.mark.parametrize("acknowledged", [True, False])
def test_under_the_clock_our_tracker_confirms_a_frame_only_once_every_reader_acknowledged_it(acknowledged):
    transport = _Acknowledging({TRACKING: acknowledged})
    _, log = _tracker(transport, "clock")
    transport.callbacks["/perception/objects"](_no_boxes(5, "perception"))
    events = [(kind, topic) for kind, topic, _ in transport.events]
    assert events == [("publish", TRACKING), ("acks", TRACKING)] + ([("publish", DELIVERED)] if acknowledged else [])
    assert transport.events[1][2] == SCHEMA["graph.timeout"].default  # as long as the player waits for a frame
    if acknowledged:
        assert parse_delivered(transport.events[-1][2]) == Delivered(TRACKING, 5)
    else:
        assert log == [f"{TRACKING}: the tracks stamped 5 were not acknowledged by every reader within 10 s; their "
                       "delivery is not confirmed"]


def test_under_the_message_drive_our_tracker_neither_waits_nor_confirms():
    transport = _Acknowledging()
    _tracker(transport, "messages")
    transport.callbacks["/perception/objects"](_no_boxes(5, "perception"))
    assert [(kind, topic) for kind, topic, _ in transport.events] == [("publish", TRACKING)]


def test_the_confirmed_flag_travels_and_defaults_to_false_for_senders_that_predate_it():
    for confirmed in (True, False):
        assert parse_ready(ready_message(RolloutReady(4, False, confirmed))).confirmed is confirmed
    assert parse_ready(type("Msg", (), {"data": '{"rollout": 4, "ahead": true}'})()) == RolloutReady(4, True, False)


def test_only_the_clock_drive_s_player_and_tracker_get_prompt_heartbeats():
    """Prompt heartbeats are for the nodes that wait for acknowledgements; in every node they cost the message
    drive a third more CPU (benchmarks/graph_bench.py)."""
    from advperc_ros.nodes.graph_nodes import SPECS
    from advperc_ros.nodes.runtime import prompt_heartbeats

    for drive in ("messages", "clock"):
        chosen = {spec.name for spec in SPECS if prompt_heartbeats(spec, {"graph.drive": drive})}
        assert chosen == ({"scenario_player", "tracker"} if drive == "clock" else set())
