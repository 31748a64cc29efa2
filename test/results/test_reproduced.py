"""`reproduced` in the report: the attack rolled out again after the search gives what the search saw,
or the report says it did not (a planner keeping state across resets, as a third-party adapter once did)."""

import json

from test_cli import write_params

from advperc_ros.cli import main
from advperc_ros.core.planners.idm import IDMPlanner
from advperc_ros.results.report import NOT_REPRODUCED


class PlannerWithAMemory(IDMPlanner):
    """The IDM planner, but each reset leaves it a little more cautious: state kept across resets, so a
    rollout's result depends on how many came before it."""

    resets = 0

    def reset(self) -> None:
        PlannerWithAMemory.resets += 1
        super().reset()

    def plan(self, t, ego, tracks):
        plan = super().plan(t, ego, tracks)
        shift = 1e-3 * PlannerWithAMemory.resets  # metres held back per rollout seen
        return type(plan)(t=plan.t, x=plan.x - shift * (plan.t - plan.t[0]), y=plan.y, yaw=plan.yaw)


def _attack(repo, tmp_path, **overrides) -> tuple[dict, str]:
    params = write_params(tmp_path / "p.yaml", repo, **overrides)
    assert main(["attack", str(params), "--output", str(tmp_path / "out"), "--quiet"]) == 0
    return json.loads((tmp_path / "out" / "report.json").read_text()), (tmp_path / "out" / "report.md").read_text()


def test_a_deterministic_planner_s_attack_is_reproduced(repo, tmp_path):
    report, markdown = _attack(repo, tmp_path)
    assert report["collision"] is True and report["reproduced"] is True
    assert "not reproduced" not in markdown


def test_a_planner_keeping_state_across_resets_is_caught(repo, tmp_path, capsys):
    report, markdown = _attack(repo, tmp_path, planner="test_reproduced:PlannerWithAMemory")
    assert report["collision"] is True and report["reproduced"] is False
    assert NOT_REPRODUCED in markdown
    printed = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert printed["reproduced"] is False

