"""ROS 2 node `orchestrator`: runs one attack from its parameters, writes the results, exits.

    ros2 run advperc_ros orchestrator --ros-args --params-file config/idm_lane_following.yaml

Parameters are those of the params file (see advperc_ros.params.SCHEMA), plus `output`, the
results folder (default results/<scenario>-seed<N>). They are validated by the same code as
`advperc attack`, so both accept and refuse exactly the same files. With `rollout_backend: graph`
every rollout goes through the node graph (advperc_ros.graph): the orchestrator starts the five
nodes itself (`graph.spawn_nodes: true`, Cyclone DDS child processes) or, with `graph.spawn_nodes:
false` (launch/attack.launch.py), drives the nodes already running through this rclpy node.
"""

import sys
from pathlib import Path
from advperc_ros.params import NODE, ParamsError, nest, parse_params

OUTPUT = "output"
ROS_OWN = {"use_sim_time", "start_type_description_service"}


def main(args: list[str] | None = None) -> int:
    try:
        import rclpy
        from rclpy.executors import ExternalShutdownException
        from rclpy.node import Node
    except ImportError:
        print("orchestrator: rclpy not found; source ROS 2 Jazzy, or run `advperc attack PARAMS` instead", file=sys.stderr)
        return 2  # the CLI's EXIT_INPUT; importing the CLI first would hide this message behind its imports

    from advperc_ros.attack import open_rollouts, resolve_bag, run_attack
    from advperc_ros.cli import EXIT_GRAPH, EXIT_INPUT, EXIT_NOTHING_TO_ATTACK, INPUT_ERRORS
    from advperc_ros.core.search.problem import GroundTruthFails
    from advperc_ros.graph import GraphError
    from advperc_ros.results import write_results
    from advperc_ros.ros.bag import read_scenario
    from advperc_ros.ros.transport import RclpyTransport

    rclpy.init(args=args)
    node = None
    code = 0
    try:
        node = Node(NODE, automatically_declare_parameters_from_overrides=True)
        flat = {name: p.value for name, p in node.get_parameters_by_prefix("").items() if name not in ROS_OWN}
        output = flat.pop(OUTPUT, "")
        try:
            params = parse_params({NODE: {"ros__parameters": nest(flat)}}, f"node '{NODE}' parameters")
            bag_path = resolve_bag(params)
            scenario = read_scenario(bag_path)
            target = Path(output or f"results/{scenario.name}-seed{params['seed']}")
            if target.exists():
                raise ParamsError(f"parameter '{OUTPUT}': {target} exists already")
            node.get_logger().info(f"attacking {scenario.name} ({params['planner']}, objective {params['objective']})")
            transport = None if params["graph.spawn_nodes"] else RclpyTransport(node)
            with open_rollouts(scenario, params, bag_path, transport) as rollouts:
                outcome = run_attack(scenario, params, progress=False, rollouts=rollouts)
            report = write_results(target, outcome, bag_path)
            node.get_logger().info(
                f"collision={report['collision']} nds={report.get('nds')} nds_t={report.get('nds_t')} "
                f"rollouts={report['rollouts']}; results in {target}"
            )
        except INPUT_ERRORS as exc:
            node.get_logger().error(str(exc))
            code = EXIT_INPUT
        except GroundTruthFails as exc:
            node.get_logger().error(str(exc))
            code = EXIT_NOTHING_TO_ATTACK
        except GraphError as exc:
            node.get_logger().error(f"graph backend: {exc}")
            code = EXIT_GRAPH
    except (KeyboardInterrupt, ExternalShutdownException):
        code = 1
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return code


if __name__ == "__main__":
    sys.exit(main())
