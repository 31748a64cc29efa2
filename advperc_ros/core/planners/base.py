"""What every planner shares: the trajectory it returns, what it knows of the road, the protocol.

A team plugs in its own planner as any class with this protocol, named `module:Class` in the
params file; it is constructed as `Class(context, **params)`.
"""

import importlib
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

import numpy as np

from advperc_ros.core.geometry import Polyline
from advperc_ros.core.scenario import EgoState, Lane


class PlannerError(ValueError):
    """A planner that cannot be found or built; the message names it."""


@dataclass(frozen=True)
class Trajectory:
    """A plan: poses at simulation times t[0] (= plan time) onward; speed is implied by the poses,
    exactly as in the nav_msgs/Path an external planner publishes."""

    t: np.ndarray  # (H,) s
    x: np.ndarray
    y: np.ndarray
    yaw: np.ndarray


@dataclass(frozen=True)
class PlanningContext:
    """The static knowledge a planner is built with: road, route, frame period, ego footprint."""

    route: Polyline
    lanes: tuple[Lane, ...]
    dt: float
    ego_length: float
    ego_width: float


@runtime_checkable
class Planner(Protocol):
    def reset(self) -> None:
        """Forget all state; called before every rollout."""

    def plan(self, t: float, ego: EgoState, tracks: dict[str, np.ndarray]) -> Trajectory:
        """Answer the tracks at time t (dict of 1-D arrays: ids, x, y, yaw, vx, vy, length, width,
        height) with a plan starting at t."""


def load_planner(name: str, context: PlanningContext, params: dict[str, Any]) -> Planner:
    """Build a bundled planner by name, or a plug-in given as `module:Class`."""
    from advperc_ros.core.planners.idm import IDMPlanner
    from advperc_ros.core.planners.obp import OBPPlanner

    bundled = {"idm": IDMPlanner, "obp": OBPPlanner}
    if name in bundled:
        cls = bundled[name]
    elif ":" in name:
        module_name, _, class_name = name.partition(":")
        try:
            cls = getattr(importlib.import_module(module_name), class_name)
        except (ImportError, AttributeError) as exc:
            raise PlannerError(f"planner '{name}' cannot be imported: {exc}") from exc
    else:
        raise PlannerError(f"unknown planner '{name}' (bundled: {', '.join(sorted(bundled))}; or module:Class)")
    try:
        planner = cls(context, **params)
    except TypeError as exc:
        raise PlannerError(f"planner '{name}' rejected its parameters: {exc}") from exc
    if not isinstance(planner, Planner):
        raise PlannerError(f"planner '{name}' lacks the planner protocol (reset() and plan(t, ego, tracks))")
    return planner
