"""Node `error_injector`: the attack function I(y, e) between ground truth and the tracker.

It holds the error tensor of the current rollout (latched /attack/errors, acknowledged on
/attack/ready so the player starts frame 0 only once the tensor is here) and turns each
/ground_truth/objects frame into /perception/objects with the same stamp: offsets added, dropped
agents removed, ghosts added, confidences from the fixed scheme of `core.perception_errors` (so the values
are those of `core.perception_errors.inject`, float for float: `core.perception_errors.inject_frame`). It
keeps the rollout's ground truth so far, as a late detection shows an agent as it was frames ago; a new
tensor starts a new history.
"""

import sys
from typing import Any

import numpy as np

from advperc_ros.core.boxes import BOX_FIELDS, BoxSequence
from advperc_ros.core.perception_errors import inject_frame
from advperc_ros.nodes.runtime import Logger, NodeSpec, ground_truth_objects, run_node
from advperc_ros.ros.interfaces.base import ObjectsLayer
from advperc_ros.ros.interfaces.registry import load_profile
from advperc_ros.ros.lockstep import RolloutErrors, RolloutReady, parse_errors, ready_message
from advperc_ros.ros.topics import CONTROL_TYPE, ERRORS, GROUND_TRUTH, READY, TOPIC_TYPES
from advperc_ros.ros.transport import Transport


class ErrorInjector:
    """The injector's logic without its process: the module docstring's node, built on any Transport,
    so tests drive it with messages and no ROS."""

    def __init__(self, transport: Transport, detections: ObjectsLayer, logger: Logger) -> None:
        self._log = logger
        self._detections = detections
        self._rollout: RolloutErrors | None = None
        self._slots: dict[int, int] = {}
        self._frames: dict[int, int] = {}
        self._history = BoxSequence.empty(0, 0)  # the rollout's ground truth so far, in the tensor's slots
        self._perception = transport.publisher(detections.topic, detections.msgtype)
        self._ready = transport.publisher(READY, CONTROL_TYPE)
        transport.subscriber(ERRORS, CONTROL_TYPE, latched=True, callback=self.on_errors)
        transport.subscriber(GROUND_TRUTH, TOPIC_TYPES[GROUND_TRUTH], callback=self.on_ground_truth, raw=True)

    def on_errors(self, msg: Any) -> None:
        rollout = parse_errors(msg)
        self._rollout = rollout
        self._slots = {int(agent): j for j, agent in enumerate(rollout.agent_ids)}
        self._frames = {int(stamp): k for k, stamp in enumerate(rollout.stamps_ns)}
        self._history = BoxSequence.empty(*rollout.errors.shape)
        self._history.ids[:] = rollout.agent_ids
        self._ready.publish(ready_message(RolloutReady(rollout.rollout, rollout.ahead, rollout.confirmed)))

    def on_ground_truth(self, data: bytes) -> None:
        stamp, truth = ground_truth_objects(data)
        if self._rollout is None or stamp not in self._frames:
            why = "no error tensor yet" if self._rollout is None else f"stamp {stamp} is not a frame of the error tensor"
            self._log.error(f"{GROUND_TRUTH}: dropped a frame ({why}); that rollout will time out")
            return
        unknown = [int(i) for i in truth["ids"] if int(i) not in self._slots]
        if unknown:
            self._log.error(f"{GROUND_TRUTH}: agents {unknown} at stamp {stamp} are not in the error tensor; frame dropped")
            return
        slots = np.array([self._slots[int(i)] for i in truth["ids"]], dtype=np.int64)
        frame = self._frames[stamp]
        self._history.valid[frame] = False
        self._history.valid[frame, slots] = True
        for name in BOX_FIELDS[:-1]:
            getattr(self._history, name)[frame, slots] = truth[name]
        perceived = inject_frame(self._history, frame, self._rollout.errors)
        self._perception.publish(self._detections.encode(perceived, stamp, "perception"))


def _build(transport: Transport, values: dict[str, Any], planner_params: dict[str, Any], logger: Logger) -> ErrorInjector:
    return ErrorInjector(transport, load_profile(values["graph.interface"]).detections, logger)


SPEC = NodeSpec("error_injector", ("graph.interface",), _build)


def main(args: list[str] | None = None) -> int:
    return run_node(SPEC, args)


if __name__ == "__main__":
    sys.exit(main())
