"""Planners by name: the bundled ones, or a plug-in given as `module:Class`.

Bundled planners are named the way plug-ins are and imported only when asked for, so the
registry imports no implementation (IDM needs no CasADi) and no module imports back into it.
"""

import importlib
from collections.abc import Mapping
from typing import Any

from advperc_ros.core.planners.base import Planner, PlanningContext
from advperc_ros.exceptions import PlannerError

BUNDLED = {
    "idm": "advperc_ros.core.planners.idm:IDMPlanner",
    "obp": "advperc_ros.core.planners.obp:OBPPlanner",
}


def load_planner(name: str, context: PlanningContext, params: Mapping[str, Any]) -> Planner:
    """Build a bundled planner by name, or a plug-in given as `module:Class`, as
    `Class(context, **params)`. Every refusal is a one-line PlannerError naming the planner."""
    if name in BUNDLED:
        target = BUNDLED[name]
    elif ":" in name:
        target = name
    else:
        raise PlannerError(f"unknown planner '{name}' (bundled: {', '.join(sorted(BUNDLED))}; or module:Class)")
    module_name, _, class_name = target.partition(":")
    try:
        cls = getattr(importlib.import_module(module_name), class_name)
    except (ImportError, AttributeError) as exc:
        raise PlannerError(f"planner '{name}' cannot be imported: {_one_line(exc)}") from exc
    except (Exception, SystemExit) as exc:  # its module fails as it runs: a bug of the plug-in, said in one line
        raise PlannerError(f"planner '{name}': importing {module_name} raised {type(exc).__name__}: "
                           f"{_one_line(exc)}") from exc
    try:
        planner = cls(context, **params)
    except (TypeError, ValueError) as exc:  # the planner's own check of its parameters
        raise PlannerError(f"planner '{name}' rejected its parameters: {_one_line(exc)}") from exc
    except (Exception, SystemExit) as exc:
        raise PlannerError(f"planner '{name}': constructing it raised {type(exc).__name__}: {_one_line(exc)}") from exc
    if not isinstance(planner, Planner):
        raise PlannerError(f"planner '{name}' lacks the planner protocol (reset() and plan(t, ego, tracks))")
    return planner


def _one_line(exc: BaseException) -> str:
    """The exception's message on one line: the CLI reports input errors as one line."""
    return " ".join(str(exc).split())
