"""The five graph nodes and the parameters each takes from an orchestrator params file.

One place for the launch file (launch/attack.launch.py) to turn a params file into per-node ROS
parameters, so `ros2 launch` and the graph backend's child processes configure the nodes alike.
"""

from pathlib import Path
from typing import Any

from advperc_ros.nodes import error_injector, planner, rule_monitor, scenario_player, tracker
from advperc_ros.nodes.runtime import NodeSpec
from advperc_ros.params import PLANNER_PARAMS, AttackParams

SPECS: tuple[NodeSpec, ...] = tuple(m.SPEC for m in (scenario_player, error_injector, tracker, planner, rule_monitor))


def ros_parameters(spec: NodeSpec, params: AttackParams, bag: Path) -> dict[str, Any]:
    """The node's parameters from validated params, `bag` absolute; the planner's keyword
    arguments as `planner_params.<key>` (a ROS parameter cannot be a mapping)."""
    values: dict[str, Any] = {name: params.get(name) for name in spec.params}
    if "bag" in values:
        values["bag"] = str(Path(bag).resolve())
    if spec.planner_params:
        values.update({f"{PLANNER_PARAMS}.{key}": value for key, value in params.planner_params.items()})
    return values
