"""ROS 2 node `orchestrator`: runs one attack from its parameters, writes the results, exits.

    ros2 run advperc_ros orchestrator --ros-args --params-file config/idm_lane_following.yaml

Parameters are those of the params file (see advperc_ros.params.SCHEMA), plus `output`, the
results folder (default as `advperc attack`'s), and `resume` (true: finish the attack that was
interrupted while writing to `output`, as `advperc attack --resume`). They are validated by the same code as `advperc
attack`, and the attack runs through the same application layer, so both accept and refuse the
same files and write the same report. A relative `bag` is looked up in the order of
`params.find_bag`; the params file of that order is the `--params-file` that set `bag`. With
`rollout_backend: graph` every rollout goes through the node graph (advperc_ros.backends.graph): the
orchestrator starts the five nodes itself as rclpy nodes (`graph.spawn_nodes: true`; `ros2 node
list` shows all six while it searches) or, with `graph.spawn_nodes: false` (launch/attack.launch.py),
drives the nodes already running, through this rclpy node either way.
"""

import json
import logging
import sys
from pathlib import Path
from typing import Any

import yaml

from advperc_ros.exceptions import ParamsError
from advperc_ros.params import NODE, nest, parse_params

OUTPUT = "output"
RESUME = "resume"  # finish the interrupted attack whose results folder was to be `output`


def params_source(args: list[str], bag: Any) -> Path | None:
    """The params file a relative `bag` is relative to: the last `--params-file` among the ROS
    arguments that sets the orchestrator's `bag` to this value (later files override earlier
    ones, as in rcl), or None when it came from `-p bag:=...`."""
    files = [Path(args[i + 1]) for i, arg in enumerate(args[:-1]) if arg == "--params-file"]
    for path in reversed(files):
        try:
            if yaml.safe_load(path.read_text())[NODE]["ros__parameters"]["bag"] == bag:
                return path
        except (OSError, UnicodeDecodeError, yaml.YAMLError, KeyError, TypeError):
            continue
    return None


class NodeLog(logging.Handler):
    """Python log records in a ROS node's log (rclpy's logger), each at its own severity."""

    def __init__(self, logger: Any) -> None:
        super().__init__(logging.INFO)
        self._logger = logger

    def emit(self, record: logging.LogRecord) -> None:
        # one call site per severity: rclpy's logger raises when a call site changes its severity
        text = record.getMessage()
        if record.levelno >= logging.ERROR:
            self._logger.error(text)
        elif record.levelno >= logging.WARNING:
            self._logger.warning(text)
        else:
            self._logger.info(text)


def main(args: list[str] | None = None) -> int:
    try:
        import rclpy  # noqa: F401
    except ImportError:
        print("orchestrator: rclpy not found; source ROS 2 Jazzy, or run `advperc attack PARAMS` instead", file=sys.stderr)
        return 2  # exits.EXIT_INPUT; importing the whole stack first would hide this message behind its imports
    from advperc_ros.application import attack_to_folder, backend_log, summary
    from advperc_ros.exceptions import Interrupted
    from advperc_ros.heap import keep_freed_heap
    from advperc_ros.nodes.runtime import given_parameters, run_rclpy
    from advperc_ros.ros.transport import RclpyTransport

    keep_freed_heap()
    argv = sys.argv[1:] if args is None else list(args)

    def body(node: Any) -> int:
        flat = given_parameters(node, argv)
        output = flat.pop(OUTPUT, "")
        resume = flat.pop(RESUME, False)
        if not isinstance(resume, bool) or (resume and not output):
            raise ParamsError(f"node '{NODE}' parameters: parameter '{RESUME}' must be true or false, and true "
                              f"only with '{OUTPUT}' (the folder of the attack to finish)")
        source = params_source(argv, flat.get("bag"))
        params = parse_params({NODE: {"ros__parameters": nest(flat)}}, str(source or f"node '{NODE}' parameters"), source)
        node.get_logger().info(f"attacking {params.bag} (objective {params.objective}, {params.rollout_backend} backend"
                               + (f", planner {params.planner})" if params.rollout_backend == "embedded" else
                                  "; the graph says which planner once it is up)"))
        transport = RclpyTransport(node)  # the graph's nodes are reached, or started as rclpy nodes, through it
        try:
            with backend_log(NodeLog(node.get_logger())):
                folder, report = attack_to_folder(params, Path(output) if output else None, transport=transport,
                                                  resume=resume, say=node.get_logger().info)
        except Interrupted as exc:  # the checkpoint is kept; say how to finish it the ROS way
            raise Interrupted(f"{exc.output}: the attack stopped with its checkpoint kept; finish it with the same "
                              f"command and -p {OUTPUT}:={exc.output} -p {RESUME}:=true (launch: output:={exc.output} "
                              f"{RESUME}:=true)") from None
        node.get_logger().info(f"{json.dumps(summary(report))}; results in {folder}")
        return 0

    return run_rclpy(NODE, argv, body, interruptible=True)


if __name__ == "__main__":
    sys.exit(main())
