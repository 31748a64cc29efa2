"""The orchestrator node: parameter plumbing everywhere, the rclpy path where ROS 2 is sourced."""

import json

import pytest
import yaml

from advperc_ros.nodes.orchestrator import main
from advperc_ros.params import nest, parse_params


def test_dotted_parameters_nest_back_into_the_params_file_layout(repo):
    document = yaml.safe_load((repo / "config" / "idm_lane_following.yaml").read_text())
    params = document["orchestrator"]["ros__parameters"]
    flat = {"bag": params["bag"], "search.random.steps": 40, "ego.width": 1.9, "planner_params.target_speed": 14.0}
    nested = nest(flat)
    assert nested["search"]["random"]["steps"] == 40
    parsed = parse_params({"orchestrator": {"ros__parameters": nested}}, "node")
    assert parsed["search.random.steps"] == 40 and parsed.planner_params == {"target_speed": 14.0}


def test_without_rclpy_the_node_says_how_to_proceed(capsys):
    try:
        import rclpy  # noqa: F401
    except ImportError:
        assert main([]) == 2
        assert "advperc attack" in capsys.readouterr().err
    else:
        pytest.skip("rclpy is installed: the ROS path is tested below")


def test_node_runs_an_attack_from_a_params_file(tmp_path, repo):
    pytest.importorskip("rclpy", reason="ROS 2 Jazzy is not sourced")
    document = yaml.safe_load((repo / "config" / "idm_lane_following.yaml").read_text())
    params = document["orchestrator"]["ros__parameters"]
    params["bag"] = str(repo / "bags" / "idm_lane_following")
    params["search"]["random"].update(steps=4, proposals=20)
    path = tmp_path / "params.yaml"
    path.write_text(yaml.safe_dump(document))
    output = tmp_path / "out"
    assert main(["--ros-args", "--params-file", str(path), "-p", f"output:={output}"]) == 0
    assert json.loads((output / "report.json").read_text())["collision"] is True
