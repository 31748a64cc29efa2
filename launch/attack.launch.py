"""Start the attack as a ROS 2 graph: player, injector, tracker, planner, rule monitor and the
orchestrator driving its search through them, all configured from one params file.

    ros2 launch advperc_ros attack.launch.py params:=config/idm_lane_following.yaml
    ros2 launch advperc_ros attack.launch.py params:=my.yaml planner:=external output:=results/mine
    ros2 launch advperc_ros attack.launch.py params:=my.yaml planner:=external interface:=autoware drive:=clock
    ros2 launch advperc_ros attack.launch.py params:=my.yaml output:=results/mine resume:=true  # after Ctrl-C
    ros2 launch advperc_ros attack.launch.py params:=my.yaml rule:=phantom_braking  # another rule (docs/rules.md)
    ros2 launch advperc_ros attack.launch.py params:=my.yaml traffic:=reactive  # agents brake for the ego

`planner:=external` leaves our planner node out: run yours on the planner topics (docs/graph.md);
`tracker:=external` leaves our tracker out: yours reads the injector's detections and publishes
the tracked objects the planner reads (docs/stacks.md).
`interface:=autoware` (or any profile of docs/plugging-in.md) makes the graph speak that stack's types
and topic names, and `drive:=clock` drives a planner that runs on a timer under use_sim_time; each
overrides the params file's `graph.interface` or `graph.drive`.
The params file is validated before any node starts; the launch ends when the orchestrator does.
The orchestrator reads the params file itself (only the graph settings are overridden), so its
report is the one `ros2 run advperc_ros orchestrator` and `advperc attack` write for that file.

`ros2 launch` itself exits 0 whatever its processes did; this launch file makes it exit with the
orchestrator's code instead (2 bad input, 4 inconclusive, 130 on Ctrl-C, ...), so a script or CI job
can tell: an argument it does not declare or a bad params file ends it with one line and code 2
before any node starts.
"""

import atexit
import json
import logging
import os
import subprocess
import sys

from ament_index_python.packages import PackageNotFoundError, get_package_prefix
from launch.actions import DeclareLaunchArgument, EmitEvent, OpaqueFunction, RegisterEventHandler
from launch.event_handlers import OnProcessExit
from launch.events import Shutdown
from launch_ros.actions import Node

from launch import LaunchDescription

PACKAGE = "advperc_ros"
ORCHESTRATOR_GRACE = 30  # s between a Ctrl-C and launch's SIGTERM to the orchestrator (launch's default: 5)
PLAN_TIMEOUT = 120  # s for the package's launch_plan to read and check the params file (it reads no bag)


def _exit_with(code: int) -> None:
    """Make the `ros2 launch` process exit with `code` once the launch has shut down: ros2launch
    returns only 0 or 1, so the code is set by the last exit handler, after output is flushed."""
    def finish() -> None:
        logging.shutdown()
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)

    if code:
        atexit.register(finish)


def _orchestrator_exited(event, context):
    """The launch ends when the orchestrator does, with its exit code (a signal's as the shell gives it)."""
    code = event.returncode if event.returncode >= 0 else 128 - event.returncode
    _exit_with(code)
    return [EmitEvent(event=Shutdown(reason=f"orchestrator exited with code {code}"))]


def _plan(context) -> dict:
    """What to start, from the package's `launch_plan` executable: installed with the shebang of the
    interpreter that built the workspace, it imports the package and its dependencies (a venv's), which
    this file, loaded by whatever interpreter runs `ros2`, does not. A refusal is its one line and code."""
    try:
        command = [os.path.join(get_package_prefix(PACKAGE), "lib", PACKAGE, "launch_plan")]
    except PackageNotFoundError:  # this file read from a source tree, not a workspace: the package is this interpreter's
        command = [sys.executable, "-m", f"{PACKAGE}.launch_plan"]
    executable = command[0]
    arguments = [f"{name}:={value}" for name, value in sorted(context.launch_configurations.items())]
    done = subprocess.run([*command, *arguments], capture_output=True, text=True, timeout=PLAN_TIMEOUT)
    if done.returncode:
        _exit_with(done.returncode)
        lines = done.stderr.strip().splitlines() or [f"{executable} exited with code {done.returncode}"]
        # `[ERROR] [launch]: Caught exception in launch ...: <line>`; a traceback (a bug) is shown whole
        raise RuntimeError(lines[-1] if len(lines) == 1 else done.stderr)
    return json.loads(done.stdout)


def _graph(context, *args, **kwargs):
    plan = _plan(context)
    nodes = [Node(package=PACKAGE, executable=node["executable"], name=node["name"], output="screen",
                  parameters=[node["parameters"]], additional_env=node["env"]) for node in plan["nodes"]]
    orchestrator_plan = plan["orchestrator"]
    # on Ctrl-C the orchestrator keeps its checkpoint and stops the search before it exits with 130; launch's
    # 5 s before SIGTERM was not always enough on a loaded machine, and the launch then ended with 143
    orchestrator = Node(package=PACKAGE, executable="orchestrator", name="orchestrator", output="screen",
                        parameters=[orchestrator_plan["params_file"], orchestrator_plan["overrides"]],
                        sigterm_timeout=str(ORCHESTRATOR_GRACE))
    stop_with_orchestrator = RegisterEventHandler(OnProcessExit(target_action=orchestrator, on_exit=_orchestrator_exited))
    return [*nodes, orchestrator, stop_with_orchestrator]


def generate_launch_description() -> LaunchDescription:
    return LaunchDescription([
        DeclareLaunchArgument("params", default_value="", description="orchestrator params YAML (as for `advperc attack`)"),
        DeclareLaunchArgument("planner", default_value="ours",
                              description="ours: start our planner node; external: leave it out and use yours"),
        DeclareLaunchArgument("tracker", default_value="ours",
                              description="ours: start our tracker node; external: leave it out and use yours (it reads "
                                          "the interface's detections and publishes its tracked objects)"),
        DeclareLaunchArgument("output", default_value="", description="results folder (default results/<scenario>-seed<N>)"),
        DeclareLaunchArgument("interface", default_value="",
                              description="the stack's message types and topic names (advperc, autoware, ...); "
                                          "default: the params file's graph.interface"),
        DeclareLaunchArgument("drive", default_value="",
                              description="messages: planners answer every tracks message; clock: planners on timers "
                                          "under use_sim_time; default: the params file's graph.drive"),
        DeclareLaunchArgument("rule", default_value="",
                              description="the driving rule to attack (docs/rules.md); "
                                          "default: the params file's rule.name"),
        DeclareLaunchArgument("traffic", default_value="",
                              description="reactive: agents keep their recorded paths but brake for the ego; replayed: "
                                          "they replay their recording (docs/traffic.md); default: the params file's "
                                          "traffic.reactive"),
        DeclareLaunchArgument("resume", default_value="false",
                              description="true: finish the attack interrupted while writing to `output`"),
        OpaqueFunction(function=_graph),
    ])
