"""The collision rule's measure, in the form the rollout's per-frame path needs: r < 0 is a contact.

The rulebook's `collision` and `at_fault_collision` rules (collision.py, at_fault_collision.py) read
what these compute; the rollout (core.rollout) and the graph's rule monitor call them directly, so
the min signed distance and the stop at contact stay one fast numpy pass per frame.

The collision rule is the signed distance between the ego's box and each agent's box: the gap
when apart, minus the penetration depth when they overlap. r(tau) is its minimum over the rollout.

At-fault collisions (nuPlan's "no ego at-fault collisions"): a contact is not the ego's fault when
the ego is stopped, or when the agent hits it from behind (the agent's centre lies behind the ego's
rear bumper in the ego's frame). No closing-speed test is needed for the latter: agents replay
their recorded motion and the ego never reverses, so an agent behind the rear bumper that touches
the ego has come from behind.
"""

from collections.abc import Sequence

import numpy as np

from advperc_ros.core.boxes import BoxSequence
from advperc_ros.core.geometry import signed_box_distance_pairs
from advperc_ros.core.scenario import EgoState

STOPPED_SPEED = 0.05  # m/s: below it the ego is stopped (nuPlan's stopped-speed threshold)


class CollisionRule:
    """The collision rule against one scenario's agents, for an ego of the given footprint.

    `distances` measures any number of frames in one numpy pass, so a rollout measures its frames
    together after the drive; during it, `may_touch` tells the few frames where the ego comes near
    enough to an agent that a contact could end the rollout, and only those are measured at once.
    """

    def __init__(self, agents: BoxSequence, ego_length: float, ego_width: float) -> None:
        self.agents, self.ego_length, self.ego_width = agents, ego_length, ego_width
        # centre distance beyond which the boxes cannot touch (half diagonals; the margin is far above
        # rounding); never for absent agents
        reach = 0.5 * (np.hypot(agents.length, agents.width) + np.hypot(ego_length, ego_width)) + 0.1
        self._reach = np.where(agents.valid, reach, -1.0)
        self._centres = agents.x + 1j * agents.y  # as complex numbers: a frame's test is four numpy calls

    def may_touch(self, ego: EgoState, k: int) -> bool:
        """Whether the ego's box may touch an agent's at frame k; if not, every distance there is > 0."""
        return bool(np.count_nonzero(np.abs(self._centres[k] - complex(ego.x, ego.y)) <= self._reach[k]) > 0)

    def distances(self, ego: np.ndarray, frames: np.ndarray | Sequence[int]) -> np.ndarray:
        """(K, N) signed distance from the ego to every agent slot at the K frames `frames`, the ego's
        states at them `ego` (K, >= 3: x, y, yaw, ...); +inf for absent agents."""
        agents = self.agents
        pairs = np.empty((2, len(frames), agents.shape[1], 5))
        pairs[0, ..., :3] = ego[:, None, :3]
        pairs[0, ..., 3:] = self.ego_length, self.ego_width
        for i, field in enumerate((agents.x, agents.y, agents.yaw, agents.length, agents.width)):
            pairs[1, ..., i] = field[frames]
        distance = signed_box_distance_pairs(pairs.reshape(2, -1, 5)).reshape(pairs.shape[1:3])
        # absent slots hold padding (zeros, or nan): cheaper to measure along than to leave out
        return np.where(agents.valid[frames], distance, np.inf)


def excusable(ego: np.ndarray, ego_length: float, agents: BoxSequence,
              stopped_speed: float = STOPPED_SPEED) -> np.ndarray:
    """(K, N) where a contact would not be the ego's fault, from the ego's states `ego` (K, 4: x, y,
    yaw, v) at frames 0..K-1: the ego stopped (below `stopped_speed`), or the agent behind its rear bumper."""
    frames = ego.shape[0]
    x, y, yaw, v = (ego[:, i : i + 1] for i in range(4))
    along = (agents.x[:frames] - x) * np.cos(yaw) + (agents.y[:frames] - y) * np.sin(yaw)
    return (v < stopped_speed) | (along < -ego_length / 2)

