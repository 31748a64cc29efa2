"""Node `planner`: a bundled or plug-in planner answering every tracks message with a plan.

It pairs /tracking/objects and /ego/odometry by stamp and answers each pair with a nav_msgs/Path
on /planning/trajectory stamped the same, each pose stamped with its own time. A planner that
raises is answered with an empty Path (and a log line): the player then marks the rollout
inconclusive, as the embedded rollout does. The first pair of a rollout (`RolloutClock`) resets the
planner; inputs left unpaired by the previous rollout are dropped. Road, route and frame period
come from the bag, as in the embedded stack; an external planner may take them from the latched
/map/lanes and /ego/route instead (docs/graph.md).
"""

import os
import sys
from typing import Any

from advperc_ros.configs import planning_context
from advperc_ros.core.planners.base import EMPTY_PLAN, Planner
from advperc_ros.core.planners.obp.compiled import CACHED_ONLY, SWITCH_ENV
from advperc_ros.core.planners.registry import load_planner
from advperc_ros.nodes.runtime import Logger, NodeSpec, run_node
from advperc_ros.ros import messages as msgs
from advperc_ros.ros.bag import read_scenario
from advperc_ros.ros.cdr import ODOMETRY as ODOMETRY_TYPE
from advperc_ros.ros.interfaces.base import Profile
from advperc_ros.ros.interfaces.registry import load_profile
from advperc_ros.ros.lockstep import StampPairs
from advperc_ros.ros.transport import Transport


class PlannerNode:
    """The planner node's logic without its process: any Planner of the registry behind the graph's
    topics, built on any Transport, so the planner under attack is the same object as embedded."""

    def __init__(self, transport: Transport, planner: Planner, profile: Profile, logger: Logger) -> None:
        self._planner = planner
        self._log = logger
        self._pairs = StampPairs(self._answer)
        self._tracks = profile.tracks
        self._ego_topic = profile.ego_topic
        self._encode_plan = profile.plan.encode
        self._plan = transport.publisher(profile.plan.topic, profile.plan.msgtype)
        transport.subscriber(profile.tracks.topic, profile.tracks.msgtype, callback=self.on_tracks, raw=True)
        transport.subscriber(profile.ego_topic, ODOMETRY_TYPE, callback=self.on_odometry, raw=True)

    def on_tracks(self, data: bytes) -> None:
        stamp, tracks = self._tracks.decode(data, self._tracks.topic)
        if stamp is None:
            self._log.error(f"{self._tracks.topic}: a MarkerArray without markers has no stamp; dropped")
            return
        self._pairs.put(0, stamp, tracks)

    def on_odometry(self, data: bytes) -> None:
        self._pairs.put(1, *msgs.ego_from_cdr(data, self._ego_topic))

    def _answer(self, stamp: int, tracks: dict, ego: Any) -> None:
        first, t = self._pairs.clock.answer(stamp)
        try:
            if first:
                self._planner.reset()
            path = self._encode_plan(self._planner.plan(t, ego, tracks), stamp)
        except (Exception, SystemExit) as exc:  # a plug-in that crashes or exits must still answer: with an empty plan
            self._log.error(f"planner raised {type(exc).__name__} at t={t:.3f} s: {exc}; answering with an empty plan")
            path = self._encode_plan(EMPTY_PLAN, stamp)
        self._plan.publish(path)


def _build(transport: Transport, values: dict[str, Any], planner_params: dict[str, Any], logger: Logger) -> PlannerNode:
    # ObP loads a compiled NLP it finds and never compiles one here: the node must be up within the graph's
    # start-up time, and a compile takes up to half a minute (core.planners.obp.compiled)
    os.environ.setdefault(SWITCH_ENV, CACHED_ONLY)
    scenario = read_scenario(values["bag"])
    planner = load_planner(values["planner"], planning_context(values, scenario), planner_params)
    return PlannerNode(transport, planner, load_profile(values["graph.interface"]), logger)


SPEC = NodeSpec("planner", ("bag", "planner", "ego.length", "ego.width", "graph.interface"), _build, planner_params=True)


def main(args: list[str] | None = None) -> int:
    return run_node(SPEC, args)


if __name__ == "__main__":
    sys.exit(main())
