"""`advperc attack --rule`: the search attacks a rule of the rulebook other than the collision rule, judging
every rollout by it, refuses to attack one the ground truth already breaks, and refuses bad rule settings
in one line with exit code 2."""

import json
import shutil

import pytest
from test_cli import write_params

from advperc_ros.cli import main
from advperc_ros.core.rules.registry import RULES


def _attack(capsys, *argv: str) -> tuple[int, str]:
    capsys.readouterr()
    code = main(["attack", *argv, "--quiet"])
    return code, capsys.readouterr().err


@pytest.fixture(scope="module")
def phantom(repo, tmp_path_factory):
    """The bundled IDM lane following attacked through phantom braking with every error kind."""
    output = tmp_path_factory.mktemp("phantom") / "attack"
    assert main(["attack", str(repo / "config" / "idm_lane_following.yaml"), "--rule", "phantom_braking", "--errors",
                 "all", "--output", str(output), "--quiet"]) == 0
    return output


def test_phantom_braking_is_attacked_at_a_high_nds_t_and_reproduces(phantom):
    report = json.loads((phantom / "report.json").read_text())
    assert report["rule"] == "phantom_braking" and report["collision"] and report["reproduced"]
    assert report["nds_t"] >= 0.9
    assert report["rules"]["phantom_braking"]["violated"] and not report["ground_truth_rules"]["phantom_braking"]["violated"]
    assert not report["rules"]["collision"]["violated"]  # it braked for nothing, it hit nothing
    assert "rule phantom_braking violated from frame" in (phantom / "report.md").read_text()


def test_every_rollout_of_the_search_is_judged_by_the_attacked_rule(phantom):
    """A ghost that makes the ego brake hard is an attack though it comes no nearer anything: the log's
    verdict column is the rule's, its distance column still the collision rule's."""
    rows = [line.split(",") for line in (phantom / "search_log.csv").read_text().splitlines()]
    header, rows = rows[0], rows[1:]
    broken = [row for row in rows if row[header.index("collided")] == "True"]
    assert broken and all(float(row[header.index("min_signed_distance")]) > 0 for row in broken)
    # the attacked rule's value is a column of its own, below 0 exactly where the verdict is a violation
    values = [float(row[header.index("rule_value")]) for row in rows]
    assert [v < 0 for v in values] == [row[header.index("collided")] == "True" for row in rows]
    assert values[0] == pytest.approx(json.loads((phantom / "report.json").read_text())
                                      ["ground_truth_rules"]["phantom_braking"]["value"], rel=1e-6)


def test_under_the_collision_rule_the_log_has_no_rule_value_column(repo, tmp_path, capsys):
    """The collision rule's value is the log's min_signed_distance already: the paper's log is unchanged."""
    capsys.readouterr()
    assert main(["attack", str(write_params(tmp_path / "p.yaml", repo)), "--output", str(tmp_path / "out"), "--quiet"]) == 0
    assert "rule_value" not in (tmp_path / "out" / "search_log.csv").read_text().splitlines()[0]
    # the line it prints names the rule and counts the rollouts left inconclusive (none here) beside the report
    printed = json.loads(capsys.readouterr().out.splitlines()[0])
    assert (printed["rule"], printed["inconclusive_rollouts"]) == ("collision", 0)


def test_a_threshold_in_the_params_is_what_every_rollout_is_judged_by(repo, phantom, tmp_path, capsys):
    """`rule.phantom_braking.min_lon_acceleration` moves the bound: the ground truth, which never brakes
    near either bound, is judged 0.44 m/s^2 nearer a violation under -2.5 than under the default -2.94,
    in the log's first row and in the report's table of every rule."""
    params = write_params(tmp_path / "p.yaml", repo, **{"rule.name": "phantom_braking",
                                                        "rule.phantom_braking.min_lon_acceleration": -2.5})
    assert _attack(capsys, str(params), "--errors", "all", "--output", str(tmp_path / "out"))[0] == 0
    judged, default = (json.loads((folder / "report.json").read_text()) for folder in (tmp_path / "out", phantom))
    truth, truth_default = (r["ground_truth_rules"]["phantom_braking"]["value"] for r in (judged, default))
    assert truth == pytest.approx(truth_default - 0.44, abs=1e-6)
    assert judged["params"]["rule.phantom_braking.min_lon_acceleration"] == -2.5


def test_a_rule_the_ground_truth_already_breaks_is_nothing_to_attack(repo, tmp_path, capsys):
    """The bundled ObP overtake turns harder than nuPlan's comfort bounds allow with perfect perception."""
    code, err = _attack(capsys, str(repo / "config" / "obp_overtake.yaml"), "--rule", "comfort", "--output",
                        str(tmp_path / "out"))
    assert code == 1 and "the stack already breaks rule comfort with perfect perception" in err, err
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("change, says", [
    ({"rule.name": "speeding"}, "parameter 'rule.name' must be one of collision, at_fault_collision"),
    ({"rule.phantom_braking.min_lon_acceleration": 2.0},
     "parameter 'rule.phantom_braking.min_lon_acceleration' must be at most 0, got 2.0"),
    ({"rule.time_to_collision.time_step": 0.0}, "parameter 'rule.time_to_collision.time_step' must be positive"),
    ({"rule.progress.min_progress_ratio": 1}, "parameter 'rule.progress.min_progress_ratio' must be a float (write 1.0)"),
    ({"rule.comfort.max_abs_yaw_rate": float("nan")}, "parameter 'rule.comfort.max_abs_yaw_rate' must be a finite number"),
    ({"rule.comfort.speed": 1.0}, "unknown parameter 'rule.comfort.speed'"),
    # the contact rules' thresholds are fixed: every backend judges them as the rollout runs
    ({"rule.at_fault_collision.stopped_speed": 0.1}, "unknown parameter 'rule.at_fault_collision.stopped_speed'"),
    ({"rule.name": "phantom_braking", "rule.at_fault_only": True},
     "parameter 'rule.at_fault_only' is true, but it is of the collision rule and rule.name is phantom_braking"),
])
def test_bad_rule_settings_are_one_line_and_exit_2(repo, tmp_path, capsys, change, says):
    params = write_params(tmp_path / "p.yaml", repo, **change)
    code, err = _attack(capsys, str(params), "--output", str(tmp_path / "out"))
    assert code == 2 and len(err.strip().splitlines()) == 1 and says in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["p.yaml"]


def test_an_unknown_rule_on_the_command_line_is_refused(repo, tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["attack", str(repo / "config" / "idm_lane_following.yaml"), "--rule", "speeding", "--quiet"])
    assert exit_.value.code == 2 and "invalid choice: 'speeding'" in capsys.readouterr().err


def test_at_fault_collision_is_the_at_fault_variant_of_the_collision_rule(repo, tmp_path, capsys):
    """`rule.name at_fault_collision` and `rule.at_fault_only true` are one configuration of the search."""
    first = write_params(tmp_path / "a.yaml", repo, **{"rule.name": "at_fault_collision"})
    second = write_params(tmp_path / "b.yaml", repo, **{"rule.at_fault_only": True})
    for params, output in ((first, "a"), (second, "b")):
        assert _attack(capsys, str(params), "--output", str(tmp_path / output))[0] == 0
    logs = [(tmp_path / name / "search_log.csv").read_text() for name in ("a", "b")]
    assert logs[0] == logs[1]
    shutil.rmtree(tmp_path / "a")


def test_the_rule_choices_are_the_registry_s(repo):
    from advperc_ros.params import SCHEMA

    assert SCHEMA["rule.name"].choices == tuple(RULES) and SCHEMA["rule.name"].default == "collision"


def test_pem_fit_refuses_an_attack_bag_whose_detections_copy_the_truth(phantom, tmp_path, capsys):
    """An attack bag's detections are the ground truth with the attack's errors: fitted, they would make a model
    of a detector without errors (scales at their floor, 20 numpy warnings); refused in one line instead."""
    capsys.readouterr()
    code = main(["pem", "fit", str(phantom / "attack"), "--output", str(tmp_path / "m.json")])
    err = capsys.readouterr().err
    assert code == 2 and len(err.strip().splitlines()) == 1 and "to the micrometre" in err, err
    assert not (tmp_path / "m.json").exists()


def test_a_replay_judges_the_rule_the_attack_broke_with_its_thresholds(repo, phantom, tmp_path, capsys):
    """Replayed on its own params the ghost still makes the ego brake for nothing, at the attack's own value;
    on an IDM that never brakes beyond 1 m/s^2 it no longer does, whatever rule that params file names."""
    report = json.loads((phantom / "report.json").read_text())
    gentle = write_params(tmp_path / "gentle.yaml", repo, **{"planner_params.max_decel": 1.0})
    for argv, verdict in (([], "still violates phantom_braking"), (["--params", str(gentle)],
                                                                   "no longer violates phantom_braking")):
        capsys.readouterr()
        assert main(["replay", str(phantom), *argv]) == 0
        replayed = json.loads(capsys.readouterr().out.splitlines()[0])
        assert (replayed["rule"], replayed["verdict"]) == ("phantom_braking", verdict)
        assert (replayed["rule_value"] < 0) == (verdict.startswith("still"))
        if not argv:
            assert replayed["rule_value"] == report["rules"]["phantom_braking"]["value"]
