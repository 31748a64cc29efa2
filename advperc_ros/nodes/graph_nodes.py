"""The five graph nodes and the parameters each takes from an orchestrator params file.

One place for the launch file (launch/attack.launch.py) to turn a params file into per-node ROS
parameters, so `ros2 launch` and the graph backend's child processes configure the nodes alike.
"""

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from advperc_ros.nodes import error_injector, planner, rule_monitor, scenario_player, tracker
from advperc_ros.nodes.runtime import NodeSpec
from advperc_ros.params import PLANNER_PARAMS, AttackParams

SPECS: tuple[NodeSpec, ...] = tuple(m.SPEC for m in (scenario_player, error_injector, tracker, planner, rule_monitor))


def ros_parameters(spec: NodeSpec, params: AttackParams, bag: Path) -> dict[str, Any]:
    """The node's parameters from validated params, `bag` absolute (`node_parameters`)."""
    return node_parameters(spec, params.values(), bag)


def node_parameters(spec: NodeSpec, values: Mapping[str, Any], bag: Path) -> dict[str, Any]:
    """The node's parameters from validated params' dotted values (`AttackParams.values()`), `bag`
    absolute; the planner's keyword arguments as `planner_params.<key>` (a ROS parameter cannot be a
    mapping)."""
    chosen: dict[str, Any] = {name: values[name] for name in spec.params}
    if "bag" in chosen:
        chosen["bag"] = str(Path(bag).resolve())
    if spec.planner_params:
        chosen.update({f"{PLANNER_PARAMS}.{key}": value for key, value in values[PLANNER_PARAMS].items()})
    return chosen
