"""Node `tracker`: the paper's Kalman + Hungarian tracker between perception and the planner.

Every /perception/objects frame is answered with /tracking/objects stamped the same (confirmed
tracks, coasting ones included). A frame stamped at or before the last answered one starts a
new rollout and resets the tracker (`RolloutClock`); the tracker's time is counted from the
rollout's first stamp, exactly as the embedded rollout counts it.
"""

import sys
from typing import Any

from advperc_ros.configs import tracker_config
from advperc_ros.core.tracker import Tracker
from advperc_ros.nodes.runtime import Logger, NodeSpec, run_node
from advperc_ros.ros import cdr
from advperc_ros.ros.lockstep import RolloutClock
from advperc_ros.ros.topics import PERCEPTION, TOPIC_TYPES, TRACKING
from advperc_ros.ros.transport import Transport


class TrackerNode:
    def __init__(self, transport: Transport, tracker: Tracker, logger: Logger) -> None:
        self._tracker = tracker
        self._log = logger
        self._clock = RolloutClock()
        self._tracks = transport.publisher(TRACKING, TOPIC_TYPES[TRACKING])
        transport.subscriber(PERCEPTION, TOPIC_TYPES[PERCEPTION], callback=self.on_detections, raw=True)

    def on_detections(self, data: bytes) -> None:
        stamp, detections = cdr.decode_objects(data, PERCEPTION)
        if stamp is None:
            self._log.error(f"{PERCEPTION}: a MarkerArray without markers has no stamp "
                            "(the first must be DELETEALL); dropped")
            return
        self._clock.observe(stamp)
        first, t = self._clock.answer(stamp)
        if first:
            self._tracker.reset()
        self._tracks.publish(cdr.encode_objects(self._tracker.step(t, detections), stamp, "tracking"))


def _build(transport: Transport, values: dict[str, Any], planner_params: dict[str, Any], logger: Logger) -> TrackerNode:
    config = tracker_config(values)
    return TrackerNode(transport, Tracker(config), logger)


SPEC = NodeSpec("tracker", ("tracker.gate", "tracker.max_age"), _build)


def main(args: list[str] | None = None) -> int:
    return run_node(SPEC, args)


if __name__ == "__main__":
    sys.exit(main())
