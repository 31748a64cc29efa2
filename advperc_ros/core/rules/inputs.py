"""What every rule reads: one frozen record of a rollout and its scenario, built in one place.

A rule is a function of the executed drive, never of the stack that drove it, so it reads only what
any backend's `RolloutResult` holds (the ego's states, its signed distances, whether the plans were
valid) and what the scenario says (the true agents, the lanes, the route).
"""

from dataclasses import dataclass

import numpy as np

from advperc_ros.core.boxes import BoxSequence
from advperc_ros.core.geometry import Polyline
from advperc_ros.core.rollout import RolloutConfig, RolloutResult, true_agents
from advperc_ros.core.scenario import Lane, Scenario


@dataclass(frozen=True)
class RuleInputs:
    """One rollout as the rules see it: frames 0..K-1 of the drive, the true agents at them, the road.

    `plan_valid` is False at the frame whose plan was missing or could not be followed (a rollout
    ends there, inconclusive: `rollout.recorded_frames`); `fallback_frames` are the frames whose plan
    the planner's own fallback answered, None when the planner does not report them. `agents` are the
    agents as they drove in this rollout: under reactive traffic its simulation, with the recording
    they left in `recorded` (None when traffic replays its recording, `agents` then being that)."""

    ego: np.ndarray  # (K, 4): x, y, yaw, v of the ego's box centre at frames 0..K-1
    dt: float  # s between frames
    agents: BoxSequence  # the true agents at frames 0..K-1 (K, N)
    distances: np.ndarray  # (K, N) the rollout's signed distance to every agent, +inf where absent
    lanes: tuple[Lane, ...]
    route: Polyline
    ego_length: float  # m
    ego_width: float  # m
    plan_valid: np.ndarray  # (K,) bool
    fallback_frames: tuple[int, ...] | None = None
    recorded: BoxSequence | None = None  # (K, N) the recording, when traffic reacted

    @property
    def num_frames(self) -> int:
        return int(self.ego.shape[0])


def rule_inputs(result: RolloutResult, scenario: Scenario, config: RolloutConfig) -> RuleInputs:
    """The rules' view of `result`, a rollout of `scenario` run with `config` (its ego footprint)."""
    frames = result.num_frames
    plan_valid = np.ones(frames, dtype=bool)
    if result.inconclusive is not None:  # the frame that made it inconclusive is its last (recorded_frames)
        plan_valid[frames - 1] = False
    return RuleInputs(
        ego=np.asarray(result.ego, dtype=float), dt=scenario.dt, agents=true_agents(result, scenario).frames(frames),
        distances=result.distances, lanes=scenario.lanes, route=scenario.route,
        ego_length=config.ego_length, ego_width=config.ego_width, plan_valid=plan_valid,
        fallback_frames=result.fallback_frames,
        recorded=None if result.agents is None else scenario.agents.frames(frames),
    )


def held(values: np.ndarray, frames: int) -> np.ndarray:
    """A reference rollout's per-frame `values` at frames 0..frames-1, its last value held beyond its
    end: a ground truth and an attacked rollout may end at different frames (a contact ends one)."""
    return np.concatenate([values, np.full(max(frames - values.size, 0), values[-1])])[:frames]
