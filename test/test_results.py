"""The results folder for people: a search that finds nothing says why, in report.md and on the terminal."""

import json

import pytest

from advperc_ros.cli import main
from advperc_ros.core.scenario_spec import build_scenario
from advperc_ros.ros.bag import write_ground_truth_bag
from test_cli import write_params
from toy_scenarios import RUNAWAY_LEAD_SPEC


def test_a_search_that_finds_nothing_says_why(repo, tmp_path, capsys):
    write_ground_truth_bag(tmp_path / "runaway", build_scenario(RUNAWAY_LEAD_SPEC))
    params = write_params(tmp_path / "params.yaml", repo, bag=str(tmp_path / "runaway"))
    capsys.readouterr()
    assert main(["attack", str(params), "--output", str(tmp_path / "out"), "--quiet"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["collision"] is False and "nds" not in summary
    for words in ("no collision found", "2 agents (1, 7)", "never made the ego collide", "closest approach 15.40 m"):
        assert words in summary["message"], words
    assert summary["closest_approach"]["min_signed_distance"] == pytest.approx(15.4)

    report = json.loads((tmp_path / "out" / "report.json").read_text())
    assert report["agents_tried"] == [1, 7] and set(report["closest_approach_by_agent"]) == {"1", "7"}
    markdown = (tmp_path / "out" / "report.md").read_text()
    assert summary["message"][1:] in markdown and "| 7 | 15.40 |" in markdown
    assert "| heuristic |" not in markdown and "N/A" not in markdown
    written = {path.name for path in (tmp_path / "out").iterdir()}
    assert written == {"report.json", "report.md", "search_log.csv", "metric_vs_rollouts.png"}
