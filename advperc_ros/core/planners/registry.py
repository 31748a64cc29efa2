"""Planners by name: the bundled ones, or a plug-in given as `module:Class`.

Bundled planners are named the way plug-ins are and imported only when asked for (`core.plugins`),
so the registry imports no implementation (IDM needs no CasADi) and no module imports back into it.
Adding a bundled planner is its module and one line of `BUNDLED`.
"""

from collections.abc import Mapping
from typing import Any

from advperc_ros.core.planners.base import Planner, PlanningContext
from advperc_ros.core.plugins import PluginKind, load, one_line
from advperc_ros.exceptions import PluginError

BUNDLED = {
    "idm": "advperc_ros.core.planners.idm:IDMPlanner",
    "obp": "advperc_ros.core.planners.obp:OBPPlanner",
}
PLANNERS = PluginKind("planner", BUNDLED, type, "a class")


def load_planner(name: str, context: PlanningContext, params: Mapping[str, Any]) -> Planner:
    """Build a bundled planner by name, or a plug-in given as `module:Class`, as
    `Class(context, **params)`. Every refusal is a one-line PluginError naming the planner."""
    cls = load(name, PLANNERS)
    try:
        planner = cls(context, **params)
    except (TypeError, ValueError) as exc:  # the planner's own check of its parameters
        raise PluginError(f"planner '{name}' rejected its parameters: {one_line(exc)}") from exc
    except (Exception, SystemExit) as exc:
        raise PluginError(f"planner '{name}': constructing it raised {type(exc).__name__}: {one_line(exc)}") from exc
    if not isinstance(planner, Planner):
        raise PluginError(f"planner '{name}' lacks the planner protocol (reset() and plan(t, ego, tracks))")
    return planner
