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

Under reactive traffic (core.traffic) a follower brakes for the ego, so one that hits it had room
to brake and is at fault, unless the ego braked harder than the hardest comfortable braking
(hard_braking's bound) within the follower's headway time before the contact: then it could not
stop, and the contact, from behind or with the ego stopped, is the ego's fault.
"""

from collections.abc import Sequence

import numpy as np

from advperc_ros.core.boxes import BoxSequence
from advperc_ros.core.geometry import signed_box_distance_pairs
from advperc_ros.core.rules.motion import MIN_LON_ACCELERATION, speed_acceleration
from advperc_ros.core.scenario import EgoState
from advperc_ros.core.traffic import IDMParameters

STOPPED_SPEED = 0.05  # m/s: below it the ego is stopped (nuPlan's stopped-speed threshold)
REACTION_TIME = IDMParameters().headway_time  # s a reactive follower has to answer the ego's braking


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

    def moved(self, k: int) -> None:
        """The agents' frame k was written anew (reactive traffic, which writes each frame as the rollout reaches it)."""
        self._centres[k] = self.agents.x[k] + 1j * self.agents.y[k]

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
              stopped_speed: float = STOPPED_SPEED, reactive_dt: float | None = None) -> np.ndarray:
    """(K, N) where a contact would not be the ego's fault, from the ego's states `ego` (K, 4: x, y,
    yaw, v) at frames 0..K-1: the ego stopped (below `stopped_speed`), or the agent behind its rear bumper.
    With `reactive_dt` (reactive traffic, frames that far apart) neither excuses a frame within
    REACTION_TIME of the ego braking beyond hard_braking's bound (`braked_too_hard`)."""
    frames = ego.shape[0]
    x, y, yaw, v = (ego[:, i : i + 1] for i in range(4))
    along = (agents.x[:frames] - x) * np.cos(yaw) + (agents.y[:frames] - y) * np.sin(yaw)
    excused = (v < stopped_speed) | (along < -ego_length / 2)
    if reactive_dt is None:
        return excused
    return excused & ~braked_too_hard(ego[:, 3], reactive_dt)[:, None]


def braked_too_hard(speeds: np.ndarray, dt: float) -> np.ndarray:
    """(K,) the frames within REACTION_TIME after the ego braked harder than hard_braking's bound (its speeds
    differentiated as that rule does): a follower braking for the ego could not have stopped behind it."""
    hard = speed_acceleration(np.asarray(speeds, dtype=float), dt) < MIN_LON_ACCELERATION
    window = int(round(REACTION_TIME / dt)) + 1
    return np.convolve(hard.astype(float), np.ones(window))[: hard.size] > 0.0

