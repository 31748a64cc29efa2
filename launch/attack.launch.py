"""Start the attack as a ROS 2 graph: player, injector, tracker, planner, rule monitor and the
orchestrator driving its search through them, all configured from one params file.

    ros2 launch advperc_ros attack.launch.py params:=config/idm_lane_following.yaml
    ros2 launch advperc_ros attack.launch.py params:=my.yaml planner:=external output:=results/mine

`planner:=external` leaves our planner node out: run yours on the planner topics (docs/graph.md).
The params file is validated before any node starts; the launch ends when the orchestrator does.
The orchestrator reads the params file itself (only the graph settings are overridden), so its
report is the one `ros2 run advperc_ros orchestrator` and `advperc attack` write for that file.
"""

from launch.actions import DeclareLaunchArgument, EmitEvent, OpaqueFunction, RegisterEventHandler
from launch.event_handlers import OnProcessExit
from launch.events import Shutdown
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from advperc_ros.nodes.graph_nodes import SPECS, ros_parameters
from advperc_ros.params import load_params, resolve_bag
from launch import LaunchDescription

PACKAGE = "advperc_ros"


def _graph(context, *args, **kwargs):
    params_file = LaunchConfiguration("params").perform(context)
    params = load_params(params_file)
    bag = resolve_bag(params).resolve()
    external = LaunchConfiguration("planner").perform(context) == "external"
    nodes = [
        Node(package=PACKAGE, executable=spec.name, name=spec.name, output="screen",
             parameters=[ros_parameters(spec, params, bag)])
        for spec in SPECS
        if not (external and spec.name == "planner")
    ]
    overrides = {"rollout_backend": "graph", "graph.spawn_nodes": False}
    output = LaunchConfiguration("output").perform(context)
    if output:
        overrides["output"] = output
    orchestrator = Node(package=PACKAGE, executable="orchestrator", name="orchestrator", output="screen",
                        parameters=[params_file, overrides])
    stop_with_orchestrator = RegisterEventHandler(
        OnProcessExit(target_action=orchestrator, on_exit=[EmitEvent(event=Shutdown(reason="orchestrator finished"))]))
    return [*nodes, orchestrator, stop_with_orchestrator]


def generate_launch_description() -> LaunchDescription:
    return LaunchDescription([
        DeclareLaunchArgument("params", description="orchestrator params YAML (as for `advperc attack`)"),
        DeclareLaunchArgument("planner", default_value="ours", choices=["ours", "external"],
                              description="ours: start our planner node; external: leave it out and use yours"),
        DeclareLaunchArgument("output", default_value="", description="results folder (default results/<scenario>-seed<N>)"),
        OpaqueFunction(function=_graph),
    ])
