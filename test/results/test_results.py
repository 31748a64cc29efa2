"""The results folder for people: a Foxglove layout that names only topics the attack bag holds, and a
search that finds nothing saying why in report.md and on the terminal."""

import json

import pytest
from rosbags.rosbag2 import Reader
from test_cli import write_params
from test_review import assert_bag_holds_the_report_s_rules
from toy_scenarios import CLOSING_LEAD_SPEC, RUNAWAY_LEAD_SPEC

from advperc_ros.cli import main
from advperc_ros.core.scenario_spec import build_scenario
from advperc_ros.results.folder import FOXGLOVE_LAYOUT, foxglove_layout
from advperc_ros.ros import bag as bags
from advperc_ros.ros import topics
from advperc_ros.ros.bag import write_ground_truth_bag


@pytest.fixture(scope="module")
def attack(repo, tmp_path_factory):
    """An attack under Autoware's interface profile: its bag holds the attacked layers in our types and in
    Autoware's."""
    base = tmp_path_factory.mktemp("attack")
    params = write_params(base / "params.yaml", repo, **{"graph.interface": "autoware"})
    assert main(["attack", str(params), "--output", str(base / "out"), "--quiet"]) == 0
    return base / "out"


def _layout_topics(layout: dict) -> dict[str, str]:
    """Every topic a layout names, with the panel naming it (message paths are `topic.field`)."""
    named = {}
    for panel, config in layout["configById"].items():
        for topic in config.get("topics", {}):
            named[topic] = panel
        for path in config.get("paths", []):
            named[path["value"].split(".")[0]] = panel
        if "topicPath" in config:
            named[config["topicPath"].split(".")[0]] = panel
    return named


def test_every_topic_of_the_foxglove_layout_is_in_the_attack_bag(attack):
    layout = json.loads((attack / FOXGLOVE_LAYOUT).read_text())
    with Reader(attack / "attack") as reader:
        in_bag = {connection.topic: connection.msgtype for connection in reader.connections}
    named = _layout_topics(layout)
    assert set(named) <= set(in_bag), set(named) - set(in_bag)
    layers = (topics.GROUND_TRUTH, topics.PERCEPTION, topics.TRACKING, topics.ODOMETRY, topics.PLAN)
    three_d = layout["configById"]["3D!attack"]["topics"]
    colours = [three_d[topic].get("color") or three_d[topic]["gradient"][0] for topic in layers]
    assert len(set(colours)) == len(layers)  # each layer its own colour
    assert named[topics.RULE].startswith("Plot!") and named[topics.SUMMARY].startswith("RawMessages!")
    assert all(named.get(topic, "").startswith("Plot!") for topic in topics.RULE_TOPICS.values())  # every rule plotted
    assert layout["configById"]["Plot!attacked_rule"]["paths"][0]["value"] == f"{topics.RULE}.data"
    assert in_bag[topics.RULE] == "std_msgs/msg/Float64"
    # every layer the bag holds in the stack's own types has a panel of its own, titled with the type
    own = {topic: msgtype for topic, msgtype in in_bag.items() if msgtype.startswith("autoware_")}
    assert set(own) == {"/perception/object_recognition/detection/objects", "/perception/object_recognition/objects",
                        "/planning/scenario_planning/trajectory"}
    for topic, msgtype in own.items():
        assert named[topic].startswith("RawMessages!"), topic
        assert layout["configById"][named[topic]]["foxglovePanelTitle"].endswith(msgtype)


def test_the_attack_bag_holds_every_rule_per_frame_as_the_report_says(attack):
    assert_bag_holds_the_report_s_rules(attack)


def test_the_layout_looks_at_the_collision(attack):
    report = json.loads((attack / "report.json").read_text())
    messages, _ = bags.read_topics(attack / "attack", {topics.ODOMETRY: topics.TOPIC_TYPES[topics.ODOMETRY]})
    position = messages[topics.ODOMETRY][report["collision_frame"]][1].pose.pose.position
    camera = json.loads((attack / FOXGLOVE_LAYOUT).read_text())["configById"]["3D!attack"]["cameraState"]
    assert camera["targetOffset"][:2] == pytest.approx([position.x, position.y])


def test_the_shipped_layout_is_the_one_attacks_write(repo):
    shipped = json.loads((repo / "config" / "foxglove_layout.json").read_text())
    assert shipped == foxglove_layout(), (
        "regenerate: python -c \"from pathlib import Path; from advperc_ros.results.folder import foxglove_layout, "
        "write_foxglove_layout; write_foxglove_layout(Path('config/foxglove_layout.json'), foxglove_layout())\"")


def test_the_results_folder_holds_the_animation_and_the_layout(attack):
    assert (attack / "attack.gif").read_bytes()[:6] == b"GIF89a"
    assert (attack / FOXGLOVE_LAYOUT).is_file() and (attack / "bev.png").is_file()


@pytest.mark.parametrize("spec, closest, why, table", [
    (RUNAWAY_LEAD_SPEC, 15.40, "no single drop brought the ego closer than perfect perception does: closest approach "
     "15.40 m", None),
    (CLOSING_LEAD_SPEC, 7.43, "closest approach 7.43 m, with agent 1 dropped (rollout 2; perfect perception 15.40 m)",
     "| 1 | 7.43 |"),
])
def test_a_search_that_finds_nothing_says_why(repo, tmp_path, capsys, spec, closest, why, table):
    write_ground_truth_bag(tmp_path / "bag", build_scenario(spec))
    params = write_params(tmp_path / "params.yaml", repo, bag=str(tmp_path / "bag"))
    capsys.readouterr()
    assert main(["attack", str(params), "--output", str(tmp_path / "out"), "--quiet"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["collision"] is False and "nds" not in summary
    for words in ("no collision found", "no agent is influential", "2 agents (1, 7)", "never made the ego collide", why):
        assert words in summary["message"], words

    report = json.loads((tmp_path / "out" / "report.json").read_text())
    assert report["agents_tried"] == [1, 7] and set(report["closest_approach_by_agent"]) == {"1", "7"}
    assert report["closest_approach"]["min_signed_distance"] == pytest.approx(closest, abs=0.005)
    # hiding both cars at once (the joint drops' one rollout, logged) does no more: the traffic never comes into
    # the ego's way
    assert report["blind"]["collided"] is False and report["joint_agents"] == []
    assert report["blind"]["min_signed_distance"] == pytest.approx(closest, abs=0.005)
    assert report["blind"]["margin"] == report["blind"]["min_signed_distance"]  # every contact counts here
    # nor does showing the cars near the ego displaced (the approach phase: all its steps, no collision)
    approach = report["approach"]
    assert approach["rollouts"] == 30 and report["rollouts"] == 4 + 30
    assert approach["closest_margin"] <= approach["start_margin"] <= closest + 0.005
    assert (f"(30 rollouts of the approach phase) brought its margin to a collision at its fault from "
            f"{approach['start_margin']:.2f} m to {approach['closest_margin']:.2f} m") in summary["message"]
    assert f"even with every vehicle hidden at once the ego collides with none at its fault (closest approach {closest:.2f} m)" \
        in summary["message"]
    markdown = (tmp_path / "out" / "report.md").read_text()
    assert summary["message"][1:] in markdown and "N/A" not in markdown
    if table is None:
        assert "| agent dropped" not in markdown  # no empty table of drops (the rules' table follows the text)
    else:
        assert table in markdown and "| 7 |" not in markdown  # only the drops that came closer
    written = {path.name for path in (tmp_path / "out").iterdir()}
    assert written == {"report.json", "report.md", "search_log.csv", "metric_vs_rollouts.png"}
