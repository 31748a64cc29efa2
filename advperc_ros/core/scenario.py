"""Ground truth of a scenario as dense arrays: agents (T, N), road lanes, ego route and start.

This is what a ground-truth bag decodes to and what every rollout reads; the search manipulates
thousands of rollouts, so agents are kept as (frames x agents) numpy arrays, not objects.
"""

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from advperc_ros.core.boxes import MAGNITUDE_BOUND, BoxSequence
from advperc_ros.core.geometry import Polyline
from advperc_ros.exceptions import ScenarioError


@dataclass(frozen=True)
class EgoState:
    """Ego pose and speed on the ground plane (rear axle is not modelled: centre of the box)."""

    x: float
    y: float
    yaw: float
    v: float


@dataclass(frozen=True)
class Lane:
    """A lane of the road map: planners use the lanes to keep to the road and to tell which agents
    share the ego's lane."""

    id: str
    centerline: Polyline
    width: float


MIN_PERIOD_NS, MAX_PERIOD_NS = 1_000_000, 60_000_000_000  # a frame period between a 1 kHz sensor's and a minute's


@dataclass(frozen=True)
class Scenario:
    """A recorded drive, what an attack is run on: the agents' ground truth (which they replay whatever
    the ego does), the road, the ego's route and start. Read from a rosbag2 bag, built from a YAML
    scenario description or imported from CommonRoad; immutable, so every rollout starts the same."""

    name: str
    stamps_ns: np.ndarray  # (T,) int64, uniformly spaced
    agents: BoxSequence  # slot j is agent j in every frame; `valid` marks presence
    lanes: tuple[Lane, ...]
    route: Polyline
    ego_start: EgoState
    # an agent's id -> the UUID (32 hex digits) its stack named it by, for a drive imported from a stack that
    # names objects by UUID (Autoware's): kept in every bag made from it, so a team's own ids travel with its attacks
    object_uuids: Mapping[int, str] = field(default_factory=dict)

    @property
    def num_frames(self) -> int:
        return int(self.stamps_ns.shape[0])

    def agent_id(self, slot: int) -> int:
        """The id of the agent in `slot` (read at its first frame present)."""
        return int(self.agents.ids[self.agents.valid[:, slot].argmax(), slot])

    @property
    def dt(self) -> float:
        return float(self.stamps_ns[1] - self.stamps_ns[0]) * 1e-9 if self.num_frames > 1 else 0.1

    @property
    def times(self) -> np.ndarray:
        """Seconds since the first frame."""
        return (self.stamps_ns - self.stamps_ns[0]) * 1e-9

    def validate(self, source: str) -> None:
        """Raise a ScenarioError naming the first of `problems`."""
        problems = self.problems(source)
        if problems:
            raise ScenarioError(problems[0])

    def problems(self, source: str) -> list[str]:
        """What makes this ground truth unusable, one line per kind of problem, each naming `source`
        and the field; empty if none. A rollout trusts what passes: finite numbers everywhere."""
        problems = []
        if self.num_frames < 2:
            problems.append(f"{source}: field 'frames' needs at least two frames, found {self.num_frames}")
        steps = np.diff(self.stamps_ns)
        if steps.size and (np.any(steps <= 0) or np.any(np.abs(steps - steps[0]) > max(1, steps[0] // 1000))):
            problems.append(f"{source}: field 'header.stamp' must increase by a constant period")
        elif steps.size and not MIN_PERIOD_NS <= steps[0] <= MAX_PERIOD_NS:  # caught here, not after a rollout of it
            problems.append(f"{source}: field 'header.stamp' steps by {int(steps[0])} ns: the frame period must be "
                            f"between {MIN_PERIOD_NS / 1e9:g} and {MAX_PERIOD_NS / 1e9:g} s")
        bad = self.agents.first_invalid_field()
        if bad is not None:
            name, k, j = bad
            agent = int(self.agents.ids[k, j])
            value = getattr(self.agents, name)[k, j]
            problems.append(f"{source}: field '{name}' of agent {agent} at frame {k} is not a valid number ({value}; "
                            f"every field finite and within {MAGNITUDE_BOUND:g}, sizes positive)")
        ego = np.array([self.ego_start.x, self.ego_start.y, self.ego_start.yaw, self.ego_start.v])
        if not np.all(np.abs(ego) <= MAGNITUDE_BOUND):
            problems.append(f"{source}: field 'ego.start' is not finite (or beyond {MAGNITUDE_BOUND:g})")
        if not np.all(np.abs(self.route.points) <= MAGNITUDE_BOUND):
            problems.append(f"{source}: field 'route' is not finite (or beyond {MAGNITUDE_BOUND:g} m)")
        for lane in self.lanes:
            if not np.all(np.abs(lane.centerline.points) <= MAGNITUDE_BOUND):
                problems.append(f"{source}: field 'centerline' of lane {lane.id!r} is not finite "
                                f"(or beyond {MAGNITUDE_BOUND:g} m)")
            if not (0.0 < lane.width <= MAGNITUDE_BOUND):
                problems.append(f"{source}: field 'width' of lane {lane.id!r} must be positive (and at most "
                                f"{MAGNITUDE_BOUND:g} m), not {lane.width}")
        return problems
