"""`advperc replay`: a found attack's errors against its own configuration (it still collides, with the
report's figures), against a more cautious planner (it no longer does), and refusals."""

import json
import shutil

import pytest
from test_cli import write_params

from advperc_ros.cli import main
from advperc_ros.replay import ATTACK_FIELDS

# a short search by the paper's method, whose attacks (the lead dropped, or displaced) these tests pin
SHORT = {"search.method": "paper", "search.random.steps": 1, "search.random.proposals": 10,
         "search.heuristic.iterations": 1, "search.refine.iterations": 0}
CAUTIOUS = {"target_speed": 14.0, "headway": 3.0}  # 3 s behind its lead rather than 1.5: hiding the lead no longer suffices


@pytest.fixture(scope="module")
def attack(repo, tmp_path_factory):
    base = tmp_path_factory.mktemp("replay")
    params = write_params(base / "params.yaml", repo, **SHORT)
    assert main(["attack", str(params), "--output", str(base / "attack"), "--quiet"]) == 0
    return base / "attack"


def _replay(args: list[str], capsys) -> dict:
    capsys.readouterr()
    assert main(["replay", *args]) == 0
    return json.loads(capsys.readouterr().out)


def test_own_params_still_collide_with_the_report_s_figures(attack, tmp_path, capsys):
    out = tmp_path / "replay"
    replayed = _replay([str(attack), "--output", str(out)], capsys)
    report = json.loads((attack / "report.json").read_text())
    assert replayed["collision"] is True and replayed["verdict"] == "still collides"
    assert replayed["min_signed_distance"] == replayed["attack_min_signed_distance"] == report["min_signed_distance"]
    assert (replayed["nds"], replayed["nds_t"]) == (report["nds"], report["nds_t"])
    written = json.loads((out / "replay.json").read_text())
    assert written["config_hash"] == written["attack_config_hash"] == report["config_hash"]
    assert (out / "replay.md").is_file() and (out / "bev.png").is_file()
    assert not list(tmp_path.glob(".*partial"))


def test_a_cautious_planner_no_longer_collides(attack, repo, tmp_path, capsys):
    params = write_params(tmp_path / "cautious.yaml", repo, planner_params=CAUTIOUS)
    out = tmp_path / "replay"
    replayed = _replay([str(attack), "--params", str(params), "--output", str(out)], capsys)
    assert replayed["collision"] is False and replayed["verdict"] == "no longer collides"
    assert replayed["min_signed_distance"] > 0 and replayed["attack_min_signed_distance"] < 0
    assert json.loads((out / "replay.json").read_text())["params"]["planner_params"] == CAUTIOUS
    assert not (out / "bev.png").exists()  # the picture is of a collision


def _refused(args: list[str], capsys) -> str:
    capsys.readouterr()
    assert main(["replay", *args]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    return err


def test_params_on_another_bag_are_refused(attack, repo, tmp_path, capsys):
    params = write_params(tmp_path / "other.yaml", repo, bag=str(repo / "bags" / "idm_overtake_follow"))
    err = _refused([str(attack), "--params", str(params), "--output", str(tmp_path / "out")], capsys)
    assert str(params) in err and "'bag'" in err and "not the scenario" in err
    assert not (tmp_path / "out").exists()


def test_a_folder_without_an_attack_is_refused(tmp_path, capsys):
    err = _refused([str(tmp_path)], capsys)
    assert "report.json" in err and str(tmp_path) in err


def test_an_output_where_nothing_can_be_made_is_refused_before_the_replay(attack, capsys):
    err = _refused([str(attack), "--output", "/proc/advperc-replay"], capsys)
    assert "/proc/advperc-replay" in err and "cannot create the output folder" in err


@pytest.mark.parametrize("field", ATTACK_FIELDS)
def test_a_report_without_a_field_the_replay_reads_is_refused(attack, tmp_path, capsys, field):
    copy = tmp_path / "attack"
    shutil.copytree(attack, copy)
    report = json.loads((copy / "report.json").read_text())
    del report[field]
    (copy / "report.json").write_text(json.dumps(report))
    assert _refused([str(copy), "--output", str(tmp_path / "out")], capsys) == (
        f"advperc: error: {copy / 'report.json'}: field '{field}' missing: not an attack report of advperc")
    assert not (tmp_path / "out").exists()
