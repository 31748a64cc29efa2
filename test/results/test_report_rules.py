"""Every report judges the attack's rollout and the ground truth's by every rule of the rulebook: the entries
agree with the report's own verdict where they measure the same thing (the collision rule is the minimum
signed distance), say null and no violation where nothing can violate a rule, and report.md shows them."""

import json
from dataclasses import replace

import pytest
from test_cli import write_params

from advperc_ros.backends.embedded import Stack
from advperc_ros.cli import main
from advperc_ros.configs import core_configs
from advperc_ros.core.perception_errors import PerceptionErrors
from advperc_ros.core.rules.registry import RULES
from advperc_ros.params import load_params, resolve_bag
from advperc_ros.results.outcome import AttackOutcome
from advperc_ros.results.report import rulebook
from advperc_ros.ros.bag import read_scenario


@pytest.fixture(scope="module")
def attack(repo, tmp_path_factory):
    base = tmp_path_factory.mktemp("rules")
    params = write_params(base / "p.yaml", repo)
    assert main(["attack", str(params), "--output", str(base / "attack"), "--quiet"]) == 0
    return base / "attack"


def _report(folder) -> dict:
    return json.loads((folder / "report.json").read_text())


def test_every_registered_rule_is_judged_on_the_attack_and_on_the_ground_truth(attack):
    report = _report(attack)
    for key in ("rules", "ground_truth_rules"):
        assert sorted(report[key]) == sorted(RULES)
        for name, entry in report[key].items():
            assert set(entry) == {"value", "violated", "frame"}, name
            assert entry["violated"] == (entry["value"] is not None and entry["value"] < 0), name
            assert (entry["frame"] is not None) == entry["violated"], name


def test_the_collision_rule_is_the_report_s_own_verdict(attack):
    report = _report(attack)
    collision = report["rules"]["collision"]
    assert collision["violated"] and report["collision"]
    assert collision["value"] == report["min_signed_distance"]
    assert collision["frame"] == report["collision_frame"]
    truth = report["ground_truth_rules"]["collision"]
    assert not truth["violated"] and truth["value"] > 0
    log = (attack / "search_log.csv").read_text().splitlines()
    header, first = log[0].split(","), log[1].split(",")  # the search's first rollout: perfect perception
    assert first[header.index("phase")] == "ground_truth"
    assert truth["value"] == pytest.approx(float(first[header.index("min_signed_distance")]), rel=1e-6)


def test_a_rollout_into_a_car_is_within_the_time_to_collision_bound_before_it_touches(attack):
    ttc = _report(attack)["rules"]["time_to_collision"]
    assert ttc["violated"] and ttc["frame"] < _report(attack)["collision_frame"]


def test_report_md_shows_every_rule_for_the_attack_and_the_ground_truth(attack):
    text = (attack / "report.md").read_text()
    assert "| rule | attack | ground truth |" in text
    for name in RULES:
        assert f"\n| {name} | " in text
    assert "| collision | **" in text  # the attack's violation is marked


def test_without_an_attack_the_ground_truth_is_still_judged(repo):
    params = load_params(repo / "config" / "idm_lane_following.yaml")
    scenario = read_scenario(resolve_bag(params))
    truth = Stack(scenario, core_configs(params)).rollout(PerceptionErrors.none(*scenario.agents.shape))
    outcome = AttackOutcome(scenario=scenario, params=params, heuristic_best=None, best=None, recorded=None, log=[],
                            wall_time_s=0.0, ground_truth=truth)
    judged = rulebook(outcome)
    assert judged["rules"] is None and list(judged["ground_truth_rules"]) == list(RULES)
    assert judged["ground_truth_rules"]["collision"]["value"] == pytest.approx(truth.min_signed_distance, rel=1e-6)
    assert rulebook(replace(outcome, ground_truth=None)) == {"rules": None, "ground_truth_rules": None}


def test_a_null_result_under_another_rule_says_how_near_its_violation_each_drop_came():
    """Under the attacked rule the diagnosis reads the log's rule_value: a drop that collided (a contact this
    rule does not count) is no "closest approach", the drop nearest a violation in r is."""
    from advperc_ros.core.search.diagnosis import why_no_collision
    from advperc_ros.core.search.problem import LogRow, Phase

    def row(rollout, phase, agent, distance, value):
        return LogRow(rollout, phase, agent, 1.0, 1.0, 1.0, distance, False, "", None, False, float("nan"), value)

    log = [row(1, Phase.GROUND_TRUTH, -1, 1.4, 4.01), row(2, Phase.HEURISTIC_DROP, 1, -0.04, 3.5),
           row(3, Phase.HEURISTIC_DROP, 2, 1.4, 2.25)]
    text = why_no_collision(log, rule="hard_braking")["message"]
    assert "nearest a violation r = 2.25, with agent 2 dropped (rollout 3; perfect perception r = 4.01)" in text
    assert "closest approach" not in text
    assert "closest approach -0.04 m, with agent 1 dropped" in why_no_collision(log)["message"]
