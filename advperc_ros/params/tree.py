"""Params between their forms: dotted values (ROS's names), the nested mapping of a params file,
and `AttackParams`. A params file uses the ROS layout (`orchestrator: ros__parameters: ...`, nested
mappings are dotted names), so the same file serves `advperc attack` and `ros2 run ...
--params-file`; any unknown key is refused.
"""

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from advperc_ros.exceptions import ParamsError
from advperc_ros.params.schema import NODE, PLANNER_PARAMS, SCHEMA, AttackParams, check_planner_params, params_from_values


def nest(flat: Mapping[str, Any]) -> dict[str, Any]:
    """Dotted parameter names back into the nested mapping of a params file."""
    out: dict[str, Any] = {}
    for name, value in flat.items():
        node = out
        *parents, leaf = name.split(".")
        for key in parents:
            node = node.setdefault(key, {})
        node[leaf] = value
    return out


def _flatten(mapping: dict, prefix: str = "") -> dict[str, Any]:
    out = {}
    for key, value in mapping.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict) and name != PLANNER_PARAMS:
            out.update(_flatten(value, f"{name}."))
        else:
            out[name] = value
    return out



def node_values(flat: dict[str, Any], names: tuple[str, ...], where: str,
                takes_planner_params: bool = False) -> tuple[dict[str, Any], dict[str, Any]]:
    """A graph node's parameters as ROS hands them over (dotted names, one by one rather than as a
    file), checked as strictly as a params file: (its `names` values, the planner's keyword
    arguments given as `planner_params.<key>` if it takes them). Any other name is refused, so no
    override a user types is silently ignored."""
    prefix = f"{PLANNER_PARAMS}."
    planner_params = {name[len(prefix):]: value for name, value in flat.items()
                      if takes_planner_params and name.startswith(prefix)}
    for name in flat:
        if name not in names and not (takes_planner_params and name.startswith(prefix)):
            takes = [*names, *([f"{prefix}<key>"] if takes_planner_params else [])]
            raise ParamsError(f"{where}: unknown parameter '{name}' (this node takes: {', '.join(takes) or 'none'})")
    values = {}
    for name in names:
        param = SCHEMA[name]
        if flat.get(name) is None:
            if param.default is None:
                raise ParamsError(f"{where}: parameter '{name}' is required")
            values[name] = param.default
        else:
            try:
                values[name] = param.check(name, flat[name])
            except ParamsError as exc:
                raise ParamsError(f"{where}: {exc}") from None
    return values, check_planner_params(where, planner_params)


def parse_params(document: Any, where: str, source: Path | None = None) -> AttackParams:
    """AttackParams from a params file's document (`orchestrator: ros__parameters: ...`)."""
    if not isinstance(document, dict) or NODE not in document:
        raise ParamsError(f"{where}: expected a top-level '{NODE}:' mapping with 'ros__parameters:'")
    unknown_nodes = sorted(str(name) for name in set(document) - {NODE})
    if unknown_nodes:
        raise ParamsError(f"{where}: unknown node '{unknown_nodes[0]}' (only '{NODE}' is configured here)")
    node = document[NODE]
    if not isinstance(node, dict) or not isinstance(node.get("ros__parameters"), dict) or len(node) != 1:
        raise ParamsError(f"{where}: '{NODE}' must hold exactly one mapping 'ros__parameters:'")
    return params_from_values(_flatten(node["ros__parameters"]), source, where)
