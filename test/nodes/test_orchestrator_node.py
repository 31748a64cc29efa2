"""The orchestrator node: parameter plumbing everywhere, the rclpy path where ROS 2 is sourced."""

import json
import os
import subprocess
import sys

import yaml

from advperc_ros.nodes.runtime import command_line_overrides
from advperc_ros.orchestrator_node import main, params_source
from advperc_ros.params import nest, parse_params


def test_dotted_parameters_nest_back_into_the_params_file_layout(repo):
    document = yaml.safe_load((repo / "config" / "idm_lane_following.yaml").read_text())
    params = document["orchestrator"]["ros__parameters"]
    flat = {"bag": params["bag"], "search.random.steps": 40, "ego.width": 1.9, "planner_params.target_speed": 14.0}
    nested = nest(flat)
    assert nested["search"]["random"]["steps"] == 40
    parsed = parse_params({"orchestrator": {"ros__parameters": nested}}, "node")
    assert parsed.search.random.steps == 40 and parsed.planner_params == {"target_speed": 14.0}


def test_without_rclpy_the_node_says_how_to_proceed():
    ros_free = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "AMENT_PREFIX_PATH", "LD_LIBRARY_PATH")}
    run = subprocess.run([sys.executable, "-c", "from advperc_ros.orchestrator_node import main; raise SystemExit(main([]))"],
                         env=ros_free, capture_output=True, text=True, timeout=120)
    assert run.returncode == 2 and "advperc attack" in run.stderr and len(run.stderr.strip().splitlines()) == 1


def test_params_source_is_the_last_params_file_that_set_the_bag(tmp_path):
    first, second = tmp_path / "a.yaml", tmp_path / "b.yaml"
    first.write_text("orchestrator:\n  ros__parameters:\n    bag: bags/x\n")
    second.write_text("orchestrator:\n  ros__parameters:\n    seed: 3\n")
    args = ["--ros-args", "--params-file", str(first), "--params-file", str(second)]
    assert params_source(args, "bags/x") == first
    assert params_source(args, "bags/y") is None  # from -p bag:=bags/y: relative to the working directory


def test_node_runs_an_attack_from_a_params_file(tmp_path, repo, ros_domain):
    """Over rclpy, with nested parameters overridden by their dotted names, as the README says."""
    document = yaml.safe_load((repo / "config" / "idm_lane_following.yaml").read_text())
    document["orchestrator"]["ros__parameters"]["bag"] = str(repo / "bags" / "idm_lane_following")
    path = tmp_path / "params.yaml"
    path.write_text(yaml.safe_dump(document))
    output = tmp_path / "out"
    overrides = ["-p", "search.random.steps:=4", "-p", "search.random.proposals:=20", "-p", "search.refine.iterations:=0"]
    assert main(["--ros-args", "--params-file", str(path), "-p", f"output:={output}", *overrides]) == 0
    report = json.loads((output / "report.json").read_text())
    assert report["collision"] is True
    chosen = report["params"]  # dotted names, as the node takes them
    assert (chosen["search.random.steps"], chosen["search.random.proposals"], chosen["search.refine.iterations"]) == (4, 20, 0)


def test_a_command_line_override_wins_over_the_params_file_wherever_it_stands(tmp_path, repo, ros_domain):
    """The README's form, `-p output:=X --params-file P -p seed:=3`: rcl alone lets the file's seed win
    once any `-p` stands before the file; the node applies what the user typed."""
    document = yaml.safe_load((repo / "config" / "idm_lane_following.yaml").read_text())
    document["orchestrator"]["ros__parameters"]["bag"] = str(repo / "bags" / "idm_lane_following")
    document["orchestrator"]["ros__parameters"]["search"] = {"random": {"steps": 40}, "refine": {"iterations": 0}}
    path = tmp_path / "params.yaml"
    path.write_text(yaml.safe_dump(document))
    output = tmp_path / "out"
    assert main(["--ros-args", "-p", f"output:={output}", "--params-file", str(path), "-p", "seed:=3",
                 "-p", "search.random.steps:=2", "-p", "search.method:=paper"]) == 0
    chosen = json.loads((output / "report.json").read_text())["params"]
    assert (chosen["seed"], chosen["search.random.steps"], chosen["search.method"]) == (3, 2, "paper")


def test_command_line_overrides_are_typed_as_rcl_types_them_and_the_last_wins():
    args = ["orchestrator", "--ros-args", "-p", "seed:=3", "--params-file", "x.yaml", "-p", "seed:=4", "-p",
            "ego.width:=2.0", "-p", "planner:=idm", "-p", "tracker:gate:=9.0", "-p", "orchestrator:objective:=nds",
            "-p", "bag:=yes", "-p", "stop_at_collision:=False"]
    assert command_line_overrides(args, "orchestrator") == {
        "seed": 4, "ego.width": 2.0, "planner": "idm", "objective": "nds", "bag": "yes", "stop_at_collision": False}
    assert command_line_overrides(["--ros-args", "-p", "seed:=1"][:1], "orchestrator") == {}


def test_a_second_interrupt_cannot_break_into_the_clean_stop_the_first_began():
    """Ctrl-C under `ros2 launch` reaches the orchestrator twice (from the terminal's process group and
    from launch): the first stops the search, the second must not raise inside the stop's own logging
    (it did, and the node died with a traceback instead of its one `interrupted:` line)."""
    import signal

    import pytest

    from advperc_ros.nodes.runtime import _interrupt

    saved = {signum: signal.signal(signum, _interrupt) for signum in (signal.SIGINT, signal.SIGTERM)}
    try:
        with pytest.raises(KeyboardInterrupt):
            os.kill(os.getpid(), signal.SIGINT)
        os.kill(os.getpid(), signal.SIGINT)  # the one launch forwards
        os.kill(os.getpid(), signal.SIGTERM)  # launch's escalation
        assert signal.getsignal(signal.SIGINT) is signal.SIG_IGN
    finally:
        for signum, handler in saved.items():
            signal.signal(signum, handler)
