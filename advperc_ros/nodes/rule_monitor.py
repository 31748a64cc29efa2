"""Node `rule_monitor`: the collision rule on the true agents and the ego, per frame.

It pairs /ground_truth/objects and /ego/odometry by stamp and answers each pair with
/rules/collision (Float64, the minimum signed distance) and /rules/diagnostics (stamped, with the
minimum and every agent's signed distance; see `ros.lockstep`). The player waits for the latter.
Inputs left unpaired when a new rollout starts (`StampPairs`) are dropped.
"""

import sys
from typing import Any

import numpy as np

from advperc_ros.core.boxes import BoxSequence
from advperc_ros.core.rules.contact import CollisionRule
from advperc_ros.nodes.runtime import Logger, NodeSpec, ground_truth_objects, run_node
from advperc_ros.ros import cdr
from advperc_ros.ros import messages as msgs
from advperc_ros.ros.lockstep import StampPairs, rule_diagnostics
from advperc_ros.ros.topics import GROUND_TRUTH, ODOMETRY, RULE, RULE_DIAGNOSTICS, TOPIC_TYPES
from advperc_ros.ros.transport import Transport


class RuleMonitor:
    """The rule monitor's logic without its process, built on any Transport: the same rule as the
    embedded rollout's (`core.rules`), judged on the true agents, never on what the planner saw."""

    def __init__(self, transport: Transport, ego_length: float, ego_width: float, logger: Logger) -> None:
        self._ego_length = ego_length
        self._ego_width = ego_width
        self._log = logger
        self._pairs = StampPairs(self._answer)
        self._rule = transport.publisher(RULE, TOPIC_TYPES[RULE])
        self._diagnostics = transport.publisher(RULE_DIAGNOSTICS, TOPIC_TYPES[RULE_DIAGNOSTICS])
        transport.subscriber(GROUND_TRUTH, TOPIC_TYPES[GROUND_TRUTH], callback=self.on_ground_truth, raw=True)
        transport.subscriber(ODOMETRY, TOPIC_TYPES[ODOMETRY], callback=self.on_odometry, raw=True)

    def on_ground_truth(self, data: bytes) -> None:
        stamp, truth = ground_truth_objects(data)
        if stamp is None:
            self._log.error(f"{GROUND_TRUTH}: a MarkerArray without markers has no stamp; dropped")
            return
        self._pairs.put(0, stamp, truth)

    def on_odometry(self, data: bytes) -> None:
        self._pairs.put(1, *msgs.ego_from_cdr(data, ODOMETRY))

    def _answer(self, stamp: int, truth: dict, ego: Any) -> None:
        self._pairs.clock.answer(stamp)
        rule = CollisionRule(BoxSequence.stack([truth]), self._ego_length, self._ego_width)
        distances = rule.distances(np.array([[ego.x, ego.y, ego.yaw]]), [0])[0]
        self._rule.publish(cdr.encode_float64(float(distances.min(initial=float("inf")))))
        self._diagnostics.publish(rule_diagnostics(stamp, truth["ids"], distances))


def _build(transport: Transport, values: dict[str, Any], planner_params: dict[str, Any], logger: Logger) -> RuleMonitor:
    return RuleMonitor(transport, values["ego.length"], values["ego.width"], logger)


SPEC = NodeSpec("rule_monitor", ("ego.length", "ego.width"), _build)


def main(args: list[str] | None = None) -> int:
    return run_node(SPEC, args)


if __name__ == "__main__":
    sys.exit(main())
