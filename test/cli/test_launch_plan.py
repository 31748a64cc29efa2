"""attack.launch.py and its launch_plan executable, without ROS: the launch file imports nothing of the
package (so `ros2` on an interpreter without the package's dependencies can load it), declares the
arguments launch_plan takes, and launch_plan turns them into the nodes to start or one refusal line
with exit code 2. The launch itself runs in test_ros2.py (with the kit sourced)."""

import ast
import json
import subprocess
import sys

import pytest
from conftest import REPO

from advperc_ros.exceptions import ParamsError
from advperc_ros.launch_plan import DEFAULTS, main, plan
from advperc_ros.nodes.graph_nodes import SPECS
from advperc_ros.params import load_params, resolve_bag
from advperc_ros.ros.topics import PROMPT_HEARTBEATS

LAUNCH_FILE = REPO / "launch" / "attack.launch.py"
PARAMS = str(REPO / "config" / "idm_lane_following.yaml")
ROS_OR_STDLIB = {"launch", "launch_ros", "ament_index_python"} | set(sys.stdlib_module_names)


def _launch_tree() -> ast.Module:
    return ast.parse(LAUNCH_FILE.read_text())


def test_the_launch_file_imports_only_ros_and_the_standard_library():
    imported = set()
    for node in ast.walk(_launch_tree()):
        if isinstance(node, ast.Import):
            imported |= {alias.name.split(".")[0] for alias in node.names}
        elif isinstance(node, ast.ImportFrom):
            imported.add((node.module or "").split(".")[0])
    assert imported and imported <= ROS_OR_STDLIB, sorted(imported - ROS_OR_STDLIB)


def test_the_launch_file_declares_every_argument_launch_plan_takes_with_its_default():
    declared = {}
    for node in ast.walk(_launch_tree()):
        if isinstance(node, ast.Call) and getattr(node.func, "id", None) == "DeclareLaunchArgument":
            default = next(k.value for k in node.keywords if k.arg == "default_value")
            declared[ast.literal_eval(node.args[0])] = ast.literal_eval(default)
    assert declared == DEFAULTS


def test_a_plan_starts_every_node_with_the_parameters_the_graph_backend_gives_them():
    launched = plan({"params": PARAMS, "output": "results/x"})
    assert [name for name, _, _ in launched.nodes] == [spec.name for spec in SPECS]
    player = {name: parameters for name, parameters, _ in launched.nodes}["scenario_player"]
    assert player["bag"] == str(resolve_bag(load_params(PARAMS)).resolve())
    assert launched.overrides == {"rollout_backend": "graph", "graph.spawn_nodes": False, "graph.interface": "advperc",
                                  "graph.drive": "messages", "output": "results/x"}
    assert json.loads(launched.to_json())["orchestrator"]["params_file"] == PARAMS
    assert all(env == {} for _, _, env in launched.nodes)  # the message drive waits for no acknowledgement


def test_under_the_clock_drive_the_player_and_tracker_start_with_prompt_heartbeats(monkeypatch):
    """They wait for every reader's acknowledgement of a frame; Cyclone, read when the node is made, asks
    for them every 100 ms unless told otherwise (docs/stacks.md)."""
    monkeypatch.setenv("CYCLONEDDS_URI", "<CycloneDDS><Domain/></CycloneDDS>")
    launched = json.loads(plan({"params": PARAMS, "drive": "clock"}).to_json())
    envs = {node["name"]: node["env"] for node in launched["nodes"]}
    prompt = {"CYCLONEDDS_URI": f"<CycloneDDS><Domain/></CycloneDDS>,{PROMPT_HEARTBEATS}"}
    assert envs == {"scenario_player": prompt, "error_injector": {}, "tracker": prompt, "planner": {},
                    "rule_monitor": {}}


def test_external_nodes_are_left_out_and_graph_arguments_override_the_params_file():
    launched = plan({"params": PARAMS, "planner": "external", "tracker": "external", "interface": "autoware",
                     "drive": "clock", "resume": "true"})
    assert {name for name, _, _ in launched.nodes} == {"scenario_player", "error_injector", "rule_monitor"}
    assert launched.overrides["graph.interface"] == "autoware" and launched.overrides["graph.drive"] == "clock"
    assert launched.overrides["resume"] is True


@pytest.mark.parametrize("words, line", [
    ([f"params:={PARAMS}", "planer:=external"],
     "unknown launch argument 'planer' (arguments: params, planner, tracker, output, resume, interface, drive, rule, "
     "traffic)"),
    ([], "launch argument 'params' is required: params:=PARAMS.yaml (as for `advperc attack`)"),
    ([f"params:={PARAMS}", "tracker:=theirs"], "launch argument 'tracker' must be ours or external, got 'theirs'"),
    ([f"params:={PARAMS}", "resume:=yes"], "launch argument 'resume' must be true or false, got 'yes'"),
    ([f"params:={PARAMS}", "drive:=fast"], "launch argument 'drive' must be messages or clock, got 'fast'"),
    (["params:=/nonexistent/p.yaml"], "/nonexistent/p.yaml: no such params file"),
    (["params"], "launch_plan: expected name:=value, got 'params'"),
])
def test_a_bad_argument_is_one_line_and_exit_code_2(capsys, words, line):
    assert main(words) == 2
    out, err = capsys.readouterr()
    assert out == "" and err.strip().splitlines() == [line]


def test_the_executable_prints_the_plan_as_one_json_object():
    done = subprocess.run([sys.executable, "-m", "advperc_ros.launch_plan", f"params:={PARAMS}"], capture_output=True,
                          text=True, timeout=120, cwd=REPO)
    assert done.returncode == 0, done.stderr
    assert [node["executable"] for node in json.loads(done.stdout)["nodes"]] == [spec.name for spec in SPECS]


def test_a_rule_argument_is_the_orchestrator_s_rule_and_is_checked():
    assert plan({"params": PARAMS, "rule": "phantom_braking"}).overrides["rule.name"] == "phantom_braking"
    with pytest.raises(ParamsError, match="launch argument 'rule' must be one of collision, at_fault_collision"):
        plan({"params": PARAMS, "rule": "speeding"})


def test_a_traffic_argument_reaches_the_orchestrator_and_the_nodes_that_move_and_judge_the_agents():
    launched = plan({"params": PARAMS, "traffic": "reactive"})
    assert launched.overrides["traffic.reactive"] is True
    parameters = {name: node_parameters for name, node_parameters, _ in launched.nodes}
    assert parameters["scenario_player"]["traffic.reactive"] is True and parameters["rule_monitor"]["traffic.reactive"]
    assert plan({"params": PARAMS}).overrides.get("traffic.reactive") is None  # the params file's, when not given
    assert main([f"params:={PARAMS}", "traffic:=ractive"]) == 2  # one line: must be reactive or replayed
