"""What a reviewer opens shows every rule of the rulebook, whichever was attacked: the attack bag holds each rule's
value per frame on a topic of its own, as report.json's `rules` say (+inf where nothing can bring a rule near a
violation); the Foxglove layout plots the attacked rule and every rule and looks where the attacked rule broke;
the bird's-eye view and the animation mark its first violation."""

import dataclasses
import json
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
import pytest
from test_cli import write_params

from advperc_ros.application import run_attack
from advperc_ros.core.rules.registry import RULES, evaluate_rulebook
from advperc_ros.params import load_params, resolve_bag
from advperc_ros.results import outcome as outcome_module
from advperc_ros.results import plots
from advperc_ros.results.folder import FOXGLOVE_LAYOUT, write_attack_bag, write_results
from advperc_ros.results.report import rule_entry, rulebook
from advperc_ros.ros import bag as bags
from advperc_ros.ros import topics
from advperc_ros.ros.bag import read_scenario
from advperc_ros.ros.lockstep import parse_rule_diagnostics


def assert_bag_holds_the_report_s_rules(folder: Path) -> None:
    """Every rule's topic in the results folder's attack bag: one Float64 per frame, whose minimum and first
    negative frame are report.json's value and frame for that rule; the diagnostics' collision value the same
    as /rules/collision's (one source)."""
    report = json.loads((folder / "report.json").read_text())
    wanted = [*topics.RULE_TOPICS.values(), topics.ODOMETRY]
    messages, _ = bags.read_topics(folder / "attack", wanted)
    frames = len(messages[topics.ODOMETRY])
    assert frames > 1 and sorted(report["rules"]) == sorted(topics.RULE_TOPICS)
    for name, topic in topics.RULE_TOPICS.items():
        values = np.array([message.data for _, message in messages[topic]])
        assert values.shape == (frames,), name
        entry = report["rules"][name]
        if entry["value"] is None:  # nothing can bring it near a violation: +inf at every frame
            assert np.all(values == np.inf), name
        else:
            assert values.min() == pytest.approx(entry["value"], rel=1e-6, abs=1e-12), name
        below = np.flatnonzero(values < 0.0)
        assert (int(below[0]) if below.size else None) == entry["frame"], name
    raw, _ = bags.read_topics(folder / "attack", [topics.RULE_DIAGNOSTICS], raw=True)
    collision = [message.data for _, message in messages[topics.RULE]]
    assert [parse_rule_diagnostics(data)[1] for _, data in raw[topics.RULE_DIAGNOSTICS]] == collision


@pytest.fixture(scope="module")
def phantom(repo, tmp_path_factory):
    """The phantom-braking attack on idm_lane_following (a ghost makes the ego brake hard for nothing): its
    outcome and its results folder."""
    base = tmp_path_factory.mktemp("phantom")
    params = load_params(write_params(base / "params.yaml", repo, **{"rule.name": "phantom_braking",
                                                                      "errors.kinds": "all"}))
    bag = resolve_bag(params)
    outcome = run_attack(read_scenario(bag), params, progress=False)
    assert outcome.best is not None
    write_results(base / "out", outcome, bag)
    return outcome, base / "out"


def _report(folder: Path) -> dict:
    return json.loads((folder / "report.json").read_text())


def test_the_phantom_attack_s_bag_holds_every_rule_as_its_report_says(phantom):
    _, folder = phantom
    rules = _report(folder)["rules"]
    assert rules["phantom_braking"]["violated"] and not rules["collision"]["violated"]
    assert rules["time_to_collision"]["value"] is None  # no agent on a collision course: +inf in the bag
    assert_bag_holds_the_report_s_rules(folder)


def test_the_layout_plots_the_attacked_rule_and_every_rule_and_looks_where_it_broke(phantom):
    outcome, folder = phantom
    layout = json.loads((folder / FOXGLOVE_LAYOUT).read_text())
    attacked = layout["configById"]["Plot!attacked_rule"]
    assert [path["value"] for path in attacked["paths"]] == ["/rules/phantom_braking.data"]
    assert attacked["foxglovePanelTitle"].startswith("phantom_braking (m/s^2)")
    every = layout["configById"]["Plot!rulebook"]["paths"]
    assert [path["value"] for path in every] == [f"{topics.RULE_TOPICS[name]}.data" for name in RULES]
    frame = _report(folder)["rules"]["phantom_braking"]["frame"]
    camera = layout["configById"]["3D!attack"]["cameraState"]
    assert camera["targetOffset"][:2] == pytest.approx(outcome.attack_rollout.ego[frame, :2])
    assert frame != outcome.attack_rollout.closest_approach()[0]  # not where the ego came closest to a car


def test_the_plots_mark_the_attacked_rule_s_first_violation(phantom):
    outcome, folder = phantom
    entry = _report(folder)["rules"]["phantom_braking"]
    mark = plots.violation_mark(outcome)
    assert mark is not None and not mark.shown_as_collision
    assert mark.frame == entry["frame"] and mark.value < 0.0
    time = outcome.scenario.times[mark.frame]
    assert mark.label == f"phantom_braking violated at t = {time:.1f} s (r = {mark.value:.2f} m/s^2)"
    fig = plots.bev_figure(outcome)
    panels = [ax for ax in fig.axes if ax.get_title()]
    assert panels[-1].get_title() == f"t = {time:.1f} s (phantom_braking violated)"
    assert mark.label in fig.get_suptitle()
    assert not any("collision" in ax.get_title() for ax in panels)  # no contact ended this drive
    plt.close(fig)


def test_the_rulebook_judges_an_outcome_once_for_the_report_the_bag_and_the_plots(phantom, monkeypatch, tmp_path):
    """Once for the attack's rollout and once for the ground truth's, whatever reads the verdicts: they cannot
    disagree, and a rule's parameters are passed in one place."""
    outcome, _ = phantom
    fresh = dataclasses.replace(outcome)  # nothing judged yet
    judged = []
    monkeypatch.setattr(outcome_module, "evaluate_rulebook",
                        lambda *given: judged.append(given) or evaluate_rulebook(*given))
    assert rulebook(fresh)["rules"] == {name: rule_entry(value) for name, value in outcome.attack_rules.items()}
    write_attack_bag(tmp_path / "attack", fresh, "{}")
    assert plots.violation_mark(fresh) == plots.violation_mark(outcome) and fresh.violation_frame == outcome.violation_frame
    assert len(judged) == 2
