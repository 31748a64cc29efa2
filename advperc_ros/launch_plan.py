"""What `ros2 launch advperc_ros attack.launch.py` starts, decided by the package's own interpreter.

`ros2` runs the interpreter it was installed with (the system's, on a ROS machine), while a team
often keeps the package's Python dependencies in a venv. A launch file that imported the package
would then fail to load (`No module named 'filterpy'`). So the launch file imports nothing of the
package: it runs this executable, which colcon installs with the shebang of the interpreter that
built the workspace (the venv's, when built from it), and reads back, as one JSON object on stdout,
the nodes to start and their parameters. A bad launch argument or params file is one line on
stderr and exit code 2, before any node starts, as from `advperc attack`.

    launch_plan params:=config/idm_lane_following.yaml planner:=external output:=results/x

Arguments are the launch file's own, `name:=value`; the JSON is
`{"nodes": [{"executable", "name", "parameters", "env"}], "orchestrator": {"params_file", "overrides"}}`, `env`
what the node's process adds to its environment (`nodes.runtime.node_environment`).
"""

import json
import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from advperc_ros.exceptions import ParamsError
from advperc_ros.exits import EXIT_INPUT, EXIT_OK, INPUT_ERRORS
from advperc_ros.nodes.graph_nodes import SPECS, ros_parameters
from advperc_ros.nodes.runtime import node_environment
from advperc_ros.params import INTERFACES, SCHEMA, load_params, resolve_bag

DEFAULTS = {"params": "", "planner": "ours", "tracker": "ours", "output": "", "resume": "false", "interface": "",
            "drive": "", "rule": "", "traffic": ""}
"""Every launch argument attack.launch.py declares and its default (the launch file reads this table)."""
GRAPH_ARGUMENTS = ("interface", "drive")  # each overrides the params file's graph.<argument> when given
NODE_ARGUMENTS = ("planner", "tracker")  # ours (started) or external (a team's node runs instead)


@dataclass(frozen=True)
class LaunchPlan:
    """The nodes one launch starts, each with its ROS parameters, and the orchestrator's overrides of
    the params file it reads itself (so its report is the one `advperc attack` writes for that file)."""

    nodes: tuple[tuple[str, dict[str, Any], dict[str, str]], ...]  # (executable, parameters, environment)
    params_file: str
    overrides: dict[str, Any]

    def to_json(self) -> str:
        return json.dumps({"nodes": [{"executable": name, "name": name, "parameters": parameters, "env": env}
                                     for name, parameters, env in self.nodes],
                           "orchestrator": {"params_file": self.params_file, "overrides": self.overrides}})


def _choice(arguments: Mapping[str, str], name: str, choices: Sequence[str]) -> str:
    value = arguments[name]
    if value not in choices:
        raise ParamsError(f"launch argument '{name}' must be {_alternatives(choices)}, got {value!r}")
    return value


def _alternatives(choices: Sequence[str]) -> str:
    return " or ".join(choices) if len(choices) == 2 else f"one of {', '.join(choices)}"


def plan(arguments: Mapping[str, str]) -> LaunchPlan:
    """The launch `arguments` (name -> value, the launch's own) turned into what to start; a
    ParamsError naming the argument or the params file's field otherwise."""
    unknown = sorted(set(arguments) - set(DEFAULTS))
    if unknown:  # `planer:=external` would otherwise attack our planner, silently
        raise ParamsError(f"unknown launch argument '{unknown[0]}' (arguments: {', '.join(DEFAULTS)})")
    given = {**DEFAULTS, **arguments}
    if not given["params"]:
        raise ParamsError("launch argument 'params' is required: params:=PARAMS.yaml (as for `advperc attack`)")
    params = load_params(given["params"])
    bag = resolve_bag(params).resolve()
    external = {name for name in NODE_ARGUMENTS if _choice(given, name, ("ours", "external")) == "external"}
    choices = {"interface": tuple(INTERFACES), "drive": SCHEMA["graph.drive"].choices}
    for name in GRAPH_ARGUMENTS:
        if given[name]:
            params = params.with_values(**{f"graph.{name}": _choice(given, name, choices[name])})
    overrides: dict[str, Any] = {"rollout_backend": "graph", "graph.spawn_nodes": False,
                                 "graph.interface": params.graph.interface, "graph.drive": params.graph.drive}
    if given["rule"]:  # the orchestrator attacks it; the nodes need not know (the rules judge in the orchestrator)
        params = params.with_values(**{"rule.name": _choice(given, "rule", SCHEMA["rule.name"].choices)})
        overrides["rule.name"] = given["rule"]
    if given["traffic"]:  # the player moves the agents, so every node gets it
        reactive = _choice(given, "traffic", ("reactive", "replayed")) == "reactive"
        params = params.with_values(**{"traffic.reactive": reactive})
        overrides["traffic.reactive"] = reactive
    if given["output"]:
        overrides["output"] = given["output"]
    if _choice(given, "resume", ("true", "false")) == "true":
        overrides["resume"] = True
    nodes = tuple((spec.name, parameters, node_environment(spec, parameters)) for spec in SPECS
                  if spec.name not in external for parameters in (ros_parameters(spec, params, bag),))
    return LaunchPlan(nodes, given["params"], overrides)


def parse_arguments(argv: Sequence[str]) -> dict[str, str]:
    """`name:=value` words as the launch passes them; a ParamsError for any other word."""
    out = {}
    for word in argv:
        name, sep, value = word.partition(":=")
        if not sep or not name:
            raise ParamsError(f"launch_plan: expected name:=value, got {word!r}")
        out[name] = value
    return out


def main(argv: list[str] | None = None) -> int:
    try:
        print(plan(parse_arguments(sys.argv[1:] if argv is None else argv)).to_json())
    except INPUT_ERRORS as exc:  # one line, as the launch shows it
        print(exc, file=sys.stderr)
        return EXIT_INPUT
    return EXIT_OK


if __name__ == "__main__":
    sys.exit(main())
