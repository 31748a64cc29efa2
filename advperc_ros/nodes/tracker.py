"""Node `tracker`: the paper's Kalman + Hungarian tracker between perception and the planner.

Every /perception/objects frame is answered with /tracking/objects stamped the same (confirmed
tracks, coasting ones included). A frame stamped at or before the last answered one starts a
new rollout and resets the tracker (`RolloutClock`); the tracker's time is counted from the
rollout's first stamp, exactly as the embedded rollout counts it. With `attacked_layer: tracks` it
tracks nothing: the perturbed objects go on as the tracks, one per agent (`core.tracker.NoTracker`).

With `graph.drive: clock` it then waits until every reader has acknowledged the tracks and says so
on /attack/delivered, the player's sign to advance /clock: a planner on a timer the clock fires then
holds the frame's tracks, so it plans on them without waiting for them itself (ros/lockstep.py).
Readers that do not acknowledge within `graph.timeout` get no confirmation: that frame times out
at the player, inconclusive, as a hung node's does.
"""

import sys
from typing import Any

from advperc_ros.configs import tracker_config
from advperc_ros.core.tracker import ObjectTracker, make_tracker
from advperc_ros.nodes.runtime import Logger, NodeSpec, run_node
from advperc_ros.ros.interfaces.base import ObjectsLayer
from advperc_ros.ros.interfaces.registry import load_profile
from advperc_ros.ros.lockstep import Delivered, RolloutClock, delivered_message
from advperc_ros.ros.topics import CONTROL_TYPE, DELIVERED
from advperc_ros.ros.transport import Transport


class TrackerNode:
    """The tracker node's logic without its process, built on any Transport: the embedded rollout's
    tracker object behind the graph's topics, so both backends track alike."""

    def __init__(self, transport: Transport, tracker: ObjectTracker, detections: ObjectsLayer, tracks: ObjectsLayer,
                 logger: Logger, confirm_within: float | None = None) -> None:
        self._tracker = tracker
        self._log = logger
        self._clock = RolloutClock()
        self._detections = detections
        self._encode_tracks = tracks.encode
        self._tracks = transport.publisher(tracks.topic, tracks.msgtype)
        self._tracks_topic = tracks.topic
        self._confirm_within = confirm_within  # (drive: clock) s to wait for the readers' acknowledgements
        self._delivered = transport.publisher(DELIVERED, CONTROL_TYPE) if confirm_within is not None else None
        transport.subscriber(detections.topic, detections.msgtype, callback=self.on_detections, raw=True)

    def on_detections(self, data: bytes) -> None:
        stamp, detections = self._detections.decode(data, self._detections.topic)
        if stamp is None:
            self._log.error(f"{self._detections.topic}: a MarkerArray without markers has no stamp "
                            "(the first must be DELETEALL); dropped")
            return
        self._clock.observe(stamp)
        first, t = self._clock.answer(stamp)
        if first:
            self._tracker.reset()
        self._tracks.publish(self._encode_tracks(self._tracker.step(t, detections), stamp, "tracking"))
        if self._delivered is not None:
            self._confirm(stamp)

    def _confirm(self, stamp: int) -> None:
        assert self._delivered is not None and self._confirm_within is not None
        if self._tracks.wait_for_acks(self._confirm_within):
            self._delivered.publish(delivered_message(Delivered(self._tracks_topic, stamp)))
        else:
            self._log.warning(f"{self._tracks_topic}: the tracks stamped {stamp} were not acknowledged by every reader "
                              f"within {self._confirm_within:g} s; their delivery is not confirmed")


def _build(transport: Transport, values: dict[str, Any], planner_params: dict[str, Any], logger: Logger) -> TrackerNode:
    profile = load_profile(values["graph.interface"])
    confirm_within = values["graph.timeout"] if values["graph.drive"] == "clock" else None
    return TrackerNode(transport, make_tracker(tracker_config(values)), profile.detections, profile.tracks, logger,
                       confirm_within)


SPEC = NodeSpec("tracker", ("tracker.gate", "tracker.max_age", "attacked_layer", "graph.interface", "graph.drive",
                            "graph.timeout"), _build, waits_for_acks=True)


def main(args: list[str] | None = None) -> int:
    return run_node(SPEC, args)


if __name__ == "__main__":
    sys.exit(main())
