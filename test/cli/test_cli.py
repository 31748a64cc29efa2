"""`advperc` end to end: attack results, bag contents, determinism, scoring, and bad input."""

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml
from mcap_ros2.reader import read_ros2_messages

from advperc_ros.cli import main
from advperc_ros.core.planners.idm import IDMPlanner
from advperc_ros.core.scenario_spec import load_scenario_spec
from advperc_ros.results.folder import load_errors
from advperc_ros.ros import bag as bags
from advperc_ros.ros import messages as msgs
from advperc_ros.ros import topics
from advperc_ros.ros.bag import open_bag_for_writing, read_topics, write_ground_truth_bag, write_scenario

SMALL_SEARCH = {"steps": 6, "proposals": 30}
PER_FRAME_TOPICS = (topics.GROUND_TRUTH, topics.PERCEPTION, topics.ODOMETRY, topics.RULE, topics.CLOCK)


def write_params(path: Path, repo: Path, **overrides) -> Path:
    document = yaml.safe_load((repo / "config" / "idm_lane_following.yaml").read_text())
    params = document["orchestrator"]["ros__parameters"]
    params["bag"] = str(repo / "bags" / "idm_lane_following")
    params["search"]["random"].update(SMALL_SEARCH)
    for dotted, value in overrides.items():
        node = params
        *parents, leaf = dotted.split(".")
        for key in parents:
            node = node.setdefault(key, {})
        node[leaf] = value
    path.write_text(yaml.safe_dump(document))
    return path


@pytest.fixture(scope="module")
def attack_run(tmp_path_factory, repo):
    """One small attack on idm_lane_following, run twice with the same seed."""
    base = tmp_path_factory.mktemp("attack")
    params = write_params(base / "params.yaml", repo)
    outputs = [base / "first", base / "second"]
    for output in outputs:
        assert main(["attack", str(params), "--output", str(output), "--quiet"]) == 0
    return outputs


def _without_wall_clock(report: dict) -> dict:
    return {k: v for k, v in report.items() if k != "wall_time_s"}


def test_results_folder_holds_everything(attack_run):
    out = attack_run[0]
    for name in ("report.json", "report.md", "search_log.csv", "metric_vs_rollouts.png", "bev.png", "attack_errors.npz"):
        assert (out / name).is_file(), name
    assert (out / "attack" / "attack.mcap").is_file() and (out / "attack" / "metadata.yaml").is_file()
    report = json.loads((out / "report.json").read_text())
    for key in ("scenario", "planner", "objective", "seed", "collision", "min_signed_distance", "nds", "nds_t",
                "fn", "tp", "mpe", "maoe", "rollouts", "wall_time_s"):
        assert key in report, key
    assert report["collision"] is True and report["min_signed_distance"] < 0
    assert report["heuristic"]["nds_t"] <= report["nds_t"]
    log_lines = (out / "search_log.csv").read_text().strip().splitlines()
    assert len(log_lines) == report["rollouts"] + 1
    assert not list(out.parent.glob(".*partial"))


def test_same_seed_gives_the_same_attack(attack_run):
    first, second = attack_run
    reports = [json.loads((out / "report.json").read_text()) for out in attack_run]
    assert _without_wall_clock(reports[0]) == _without_wall_clock(reports[1])
    assert (first / "search_log.csv").read_text() == (second / "search_log.csv").read_text()
    assert load_errors(first / "attack_errors.npz").equals(load_errors(second / "attack_errors.npz"))


def test_attack_bag_decodes_with_rosbags_and_mcap_ros2(attack_run):
    out = attack_run[0]
    report = json.loads((out / "report.json").read_text())
    messages, custom = read_topics(out / "attack", topics.TOPIC_TYPES)
    frames = report["collision_frame"] + 1
    for topic in PER_FRAME_TOPICS:
        assert len(messages[topic]) == frames, topic
    assert len(messages[topics.TRACKING]) == len(messages[topics.PLAN]) == frames - 1  # none after the collision
    rules = [m.data for _, m in messages[topics.RULE]]
    assert rules[-1] == pytest.approx(report["min_signed_distance"]) and rules[-1] < 0
    assert json.loads(messages[topics.SUMMARY][0][1].data)["nds_t"] == report["nds_t"]
    assert custom[bags.SCENARIO_KEY] == "idm_lane_following"

    independent = {}
    for message in read_ros2_messages(str(out / "attack" / "attack.mcap")):
        independent.setdefault(message.channel.topic, []).append(message.ros_msg)
    for topic in PER_FRAME_TOPICS:
        assert len(independent[topic]) == frames, topic
    assert independent[topics.RULE][-1].data == pytest.approx(rules[-1])
    plan = independent[topics.PLAN][0]
    assert len(plan.poses) > 2 and plan.header.frame_id == "map"


def test_score_of_the_attack_bag_reproduces_the_report(attack_run, repo, capsys):
    out = attack_run[0]
    report = json.loads((out / "report.json").read_text())
    capsys.readouterr()
    assert main(["score", str(repo / "bags" / "idm_lane_following"), str(out / "attack")]) == 0
    scored = json.loads(capsys.readouterr().out)
    assert scored["frames"] == report["collision_frame"] + 1
    for key in ("nds", "nds_t", "mpe", "maoe"):
        assert scored[key] == pytest.approx(report[key], abs=1e-9), key
    for key in ("fn", "tp", "fp"):
        assert scored[key] == report[key], key


# ----- bad input: one line naming file and field, exit 2, nothing written -------------------------


def _run_bad(args: list[str], output: Path, capsys) -> str:
    capsys.readouterr()
    code = main([*args, "--output", str(output), "--quiet"])
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert len(err.splitlines()) == 1, err
    assert not output.exists()
    assert not list(output.parent.glob(f".{output.name}*"))
    return err


def test_missing_bag(tmp_path, repo, capsys):
    params = write_params(tmp_path / "p.yaml", repo, bag=str(tmp_path / "nowhere"))
    err = _run_bad(["attack", str(params)], tmp_path / "out", capsys)
    assert str(params) in err and "'bag'" in err


def test_bag_without_ground_truth(tmp_path, repo, capsys):
    with open_bag_for_writing(tmp_path / "clock_only") as bag:
        bag.write(topics.CLOCK, 0, msgs.clock(0))
    params = write_params(tmp_path / "p.yaml", repo, bag=str(tmp_path / "clock_only"))
    err = _run_bad(["attack", str(params)], tmp_path / "out", capsys)
    assert "clock_only" in err and "/ground_truth/objects" in err


def test_malformed_bag(tmp_path, repo, capsys):
    broken = tmp_path / "broken"
    broken.mkdir()
    (broken / "metadata.yaml").write_text("rosbag2_bagfile_information: {version: 9}\n")
    (broken / "broken.mcap").write_bytes(b"not an mcap file")
    params = write_params(tmp_path / "p.yaml", repo, bag=str(broken))
    err = _run_bad(["attack", str(params)], tmp_path / "out", capsys)
    assert "broken" in err and "bag" in err


@pytest.mark.parametrize(
    "override, words",
    [
        ({"search.random.stepz": 3}, ["unknown parameter", "search.random.stepz"]),
        ({"search.random.max_offset": 5}, ["search.random.max_offset", "float"]),
        ({"search.random.steps": 4.0}, ["search.random.steps", "int"]),
        ({"objective": "map"}, ["objective", "nds_t"]),
        ({"seed": True}, ["seed", "int"]),
    ],
)
def test_wrong_params(tmp_path, repo, capsys, override, words):
    params = write_params(tmp_path / "p.yaml", repo, **override)
    err = _run_bad(["attack", str(params)], tmp_path / "out", capsys)
    assert str(params) in err
    for word in words:
        assert word in err


def test_unknown_planner(tmp_path, repo, capsys):
    params = write_params(tmp_path / "p.yaml", repo, planner="mpc_of_dreams")
    err = _run_bad(["attack", str(params)], tmp_path / "out", capsys)
    assert "mpc_of_dreams" in err


def test_nan_in_ground_truth(tmp_path, repo, capsys):
    scenario = load_scenario_spec(repo / "scenarios" / "idm_lane_following.yaml")
    scenario.agents.x[3, 0] = math.nan
    write_ground_truth_bag(tmp_path / "nan_bag", scenario)
    params = write_params(tmp_path / "p.yaml", repo, bag=str(tmp_path / "nan_bag"))
    err = _run_bad(["attack", str(params)], tmp_path / "out", capsys)
    assert "nan_bag" in err and "'x'" in err and "frame 3" in err


def test_ground_truth_that_already_collides_is_not_attacked(tmp_path, repo, capsys):
    spec = yaml.safe_load((repo / "scenarios" / "idm_lane_following.yaml").read_text())
    spec["agents"][0]["start_s"] = 203.0  # the lead overlaps the ego from the start
    from advperc_ros.core.scenario_spec import build_scenario

    write_ground_truth_bag(tmp_path / "crash", build_scenario(spec))
    params = write_params(tmp_path / "p.yaml", repo, bag=str(tmp_path / "crash"))
    capsys.readouterr()
    code = main(["attack", str(params), "--output", str(tmp_path / "out"), "--quiet"])
    assert code == 1
    assert "perfect perception" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_make_bags_refuses_to_overwrite_and_rewrites_with_force(tmp_path, repo, capsys):
    spec = repo / "scenarios" / "idm_lane_following.yaml"
    assert main(["make-bags", str(spec), "--output-dir", str(tmp_path)]) == 0
    assert main(["make-bags", str(spec), "--output-dir", str(tmp_path)]) == 2
    assert main(["make-bags", str(spec), "--output-dir", str(tmp_path), "--force"]) == 0
    assert (tmp_path / "idm_lane_following" / "idm_lane_following.mcap").is_file()
    shutil.rmtree(tmp_path / "idm_lane_following")


def test_write_scenario_round_trip_keeps_everything(tmp_path, repo):
    from advperc_ros.ros.bag import read_scenario

    scenario = load_scenario_spec(repo / "scenarios" / "idm_overtake_follow.yaml")
    with open_bag_for_writing(tmp_path / "rt") as bag:
        write_scenario(bag, scenario)
    back = read_scenario(tmp_path / "rt")
    assert back.name == scenario.name and back.num_frames == scenario.num_frames
    valid = scenario.agents.valid
    np.testing.assert_allclose(back.agents.yaw[valid], scenario.agents.yaw[valid], atol=1e-12)
    np.testing.assert_allclose(back.agents.vx[valid], scenario.agents.vx[valid], atol=1e-9)
    assert [lane.id for lane in back.lanes] == [lane.id for lane in scenario.lanes]


def test_robustness_at_zero_strength_reproduces_the_attack(attack_run, tmp_path, capsys):
    import csv

    out = tmp_path / "attack"  # a copy: the attack folder is shared by other tests
    shutil.copytree(attack_run[0], out)
    report = json.loads((out / "report.json").read_text())
    assert main(["robustness", str(out), "--strengths", "0,0.5", "--samples", "2"]) == 0
    rows = list(csv.DictReader((out / "robustness.csv").open()))
    assert [float(r["strength"]) for r in rows] == [0.0, 0.5]
    assert float(rows[0]["adversarial_fraction"]) == 1.0
    assert float(rows[0]["mean_metric"]) == pytest.approx(report["nds_t"], abs=1e-12)
    assert (out / "robustness.png").is_file() and not list(out.glob(".robustness*"))


def test_robustness_needs_an_attack(tmp_path, capsys):
    assert main(["robustness", str(tmp_path)]) == 2
    assert "report.json" in capsys.readouterr().err


def test_attack_with_the_pem_objective_given_on_the_command_line(tmp_path, repo):
    params = write_params(tmp_path / "p.yaml", repo)  # objective: nds_t in the file
    assert main(["attack", str(params), "--output", str(tmp_path / "out"), "--quiet", "--objective", "pem_ll"]) == 0
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    assert report["collision"] and report["objective"] == "pem_ll"
    assert report["pem_ll"] >= report["heuristic"]["pem_ll"]
    assert "PEM LL" in (tmp_path / "out" / "report.md").read_text()


def test_check_typical_passes_on_a_bundled_scenario(repo, capsys):
    capsys.readouterr()
    assert main(["check-typical", str(repo / "config" / "idm_overtake_follow.yaml"), "--samples", "5"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["passed"] and result["collisions"] == 0 and result["samples"] == 5


class PlannerFailingAfterGroundTruth(IDMPlanner):
    """The IDM planner, raising in every plan after the first rollout (the ground truth): a plug-in
    that breaks once the search starts."""

    rollouts = -1  # IDMPlanner's constructor resets too

    def reset(self) -> None:
        PlannerFailingAfterGroundTruth.rollouts += 1
        super().reset()

    def plan(self, t, ego, tracks):
        if PlannerFailingAfterGroundTruth.rollouts >= 2:
            raise ValueError("lost its map")
        return super().plan(t, ego, tracks)


def test_a_search_whose_rollouts_were_mostly_inconclusive_ends_with_4_not_no_collision(repo, tmp_path, capsys):
    PlannerFailingAfterGroundTruth.rollouts = -1
    params = write_params(tmp_path / "p.yaml", repo, planner="test_cli:PlannerFailingAfterGroundTruth")
    capsys.readouterr()
    assert main(["attack", str(params), "--output", str(tmp_path / "out"), "--quiet"]) == 4
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "rollouts were inconclusive, so the search cannot say that no collision" \
        in err and "lost its map" in err, err
    assert sorted(path.name for path in tmp_path.iterdir()) == ["p.yaml"]  # no report, no checkpoint to block a rerun
