"""Is a collision avoidable at all? Recorded traffic does not react to the ego.

The ego may follow its route with any constant acceleration within physical limits (speed kept in
[0, max_speed]); if every such profile collides with some recorded vehicle, no planner could avoid
it and the scenario says nothing about perception. Constant accelerations are a subset of all ego
motions, so this rejects only what a simple profile cannot escape, never an avoidable scenario
that one of them escapes.
"""

import numpy as np

from advperc_ros.core.geometry import box_corners, signed_box_distance
from advperc_ros.core.scenario import Scenario
from advperc_ros.exceptions import ScenarioRejected as ScenarioRejected  # re-exported: its home before exceptions.py


def escape_profiles(
    scenario: Scenario,
    ego_length: float,
    ego_width: float,
    accelerations: np.ndarray,
    max_speed: float,
) -> np.ndarray:
    """Minimum signed distance to any agent over the scenario, per constant-acceleration profile."""
    t = scenario.times
    s0 = float(scenario.route.project(np.array([scenario.ego_start.x, scenario.ego_start.y]))[0])
    agents = scenario.agents
    frames, slots = np.nonzero(agents.valid)
    agent_boxes = box_corners(
        agents.x[frames, slots], agents.y[frames, slots], agents.yaw[frames, slots],
        agents.length[frames, slots], agents.width[frames, slots],
    )
    out = np.full(len(accelerations), np.inf)
    for i, accel in enumerate(accelerations):
        v = np.clip(scenario.ego_start.v + accel * t, 0.0, max_speed)
        s = s0 + np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * np.diff(t))])
        xy = scenario.route.position(s)
        ego = box_corners(xy[:, 0], xy[:, 1], scenario.route.heading(s), ego_length, ego_width)
        if frames.size:
            out[i] = signed_box_distance(ego[frames], agent_boxes).min()
    return out


def unavoidable_collision(
    scenario: Scenario,
    ego_length: float,
    ego_width: float,
    max_decel: float = 8.0,
    max_accel: float = 3.0,
    max_speed: float = 40.0,
    profiles: int = 23,
) -> str | None:
    """Why a collision is unavoidable, or None if some profile escapes every recorded vehicle."""
    accelerations = np.linspace(-max_decel, max_accel, profiles)
    margins = escape_profiles(scenario, ego_length, ego_width, accelerations, max_speed)
    if np.any(margins >= 0.0):
        return None
    best = int(np.argmax(margins))
    return (
        f"recorded traffic hits the ego whatever it does: all {profiles} constant accelerations from "
        f"{-max_decel:g} to {max_accel:g} m/s^2 along the route collide (best {accelerations[best]:+.2f} m/s^2 "
        f"still overlaps by {-margins[best]:.2f} m)"
    )
