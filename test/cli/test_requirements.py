"""`advperc requirements`: the bracket of a case whose tolerance is known in closed form holds it, every
broken bound names an attack that breaks the rule inside the requirement's space, the outputs, resuming, the
executors, and refusals before any search.

The closed-form case: the ego stands 1 m (IDM's min_gap, its equilibrium at rest) behind a parked car, and the
tracker drops a track at its first missed frame. While the car is missed, IDM sees a free road and accelerates
at max_accel a; once the car is seen again it brakes at max_decel b (its clip, far below what IDM asks for that
close). After a miss of t s it has covered a t^2 / 2 and needs (a t)^2 / (2 b) more to stop, so it hits the car
when a t^2 / 2 + (a t)^2 / (2 b) > 1 m: with a = 1 and b = 3 m/s^2, for t > sqrt(1.5) = 1.22 s, 12 frames of
0.1 s tolerated and 13 not. Misses spread over the scenario add up (a frame seen between them only brakes), so
a requirement on the total time missed has the same tolerance."""

import json
import math
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from toy_scenarios import FOLLOW_SPEC

from advperc_ros.cli import main
from advperc_ros.core.perception_errors.restriction import DEFAULT_ITERATIONS, MAGNITUDES
from advperc_ros.core.scenario_spec import build_scenario
from advperc_ros.results.folder import load_errors
from advperc_ros.ros.bag import write_ground_truth_bag

GAP, ACCEL, DECEL, DT = 1.0, 1.0, 3.0, 0.1
TOLERATED = math.sqrt(GAP / (ACCEL / 2 + ACCEL**2 / (2 * DECEL)))  # s: 1.2247
STANDING = {**FOLLOW_SPEC, "name": "standing", "duration": 6.0,
            "ego": {"route": ["east"], "start_s": 100.0, "speed": 0.0},
            "agents": [{"id": 1, "lane": "east", "start_s": 100.0 + 4.6 + GAP, "speed": 0.0, "size": [4.6, 1.9, 1.6]}]}


def standing_params(folder: Path) -> Path:
    write_ground_truth_bag(folder / "bag", build_scenario(STANDING))
    params = {"bag": str(folder / "bag"), "planner": "idm",
              "planner_params": {"target_speed": 14.0, "min_gap": GAP, "max_accel": ACCEL, "max_decel": DECEL},
              "tracker": {"max_age": DT}, "search": {"budget": 30}}
    (folder / "standing.yaml").write_text(yaml.safe_dump({"orchestrator": {"ros__parameters": params}}))
    return folder / "standing.yaml"


def requirements(params: Path, output: Path, *flags: str, capsys) -> dict:
    capsys.readouterr()
    code = main(["requirements", str(params), "--output", str(output), "--quiet", *flags])
    out = capsys.readouterr()
    assert code == 0, out.err
    return json.loads(out.out)


@pytest.fixture(scope="module")
def standing(tmp_path_factory) -> tuple[Path, Path]:
    """(params, output) of the closed-form case's drop requirement in one bin and one beyond: read only."""
    folder = tmp_path_factory.mktemp("standing")
    params = standing_params(folder)
    assert main(["requirements", str(params), "--output", str(folder / "out"), "--kinds", "drop", "--bins", "20,40",
                 "--executor", "serial", "--quiet"]) == 0
    return params, folder / "out"


def rows(output: Path) -> list[dict]:
    return json.loads((output / "requirements.json").read_text())


def test_the_bracket_holds_the_closed_form_tolerance(standing):
    near, far = rows(standing[1])
    assert (near["kind"], near["bin"], near["rule"]) == ("drop", "0-20 m", "collision")
    frames = math.floor(TOLERATED / DT)  # the longest miss in whole frames that the ego survives: 12
    # tolerated up to a magnitude that allows the 12 frames (not 13), broken at one that allows 13 or more
    assert math.floor(near["tolerated"] / DT + 1e-9) == frames, near
    assert near["breaks_at"] is not None and math.floor(near["breaks_at"] / DT + 1e-9) >= frames + 1, near
    largest = MAGNITUDES["drop"].largest
    assert near["breaks_at"] - near["tolerated"] <= largest / 2**DEFAULT_ITERATIONS + 1e-9  # the halvings of [0, largest]
    # no car is ever 20-40 m away: nothing to miss there, nothing broken up to the kind's largest magnitude
    assert (far["bin"], far["tolerated"], far["breaks_at"], far["attack"], far["searches"]) == ("20-40 m", largest, None,
                                                                                             None, 1)
    # the statistical side: the shipped PEM's typical errors, missed frames bounded by the tolerated total, never
    # collide (any 12 missed frames are survived, however spread)
    assert (near["typical_samples"], near["typical_violations"]) == (10, 0)


def test_the_attack_that_breaks_the_bound_breaks_the_rule_inside_the_requirement(standing):
    _, output = standing
    near = rows(output)[0]
    folder = output / near["attack"]
    report = json.loads((folder / "report.json").read_text())
    assert report["collision"] is True and report["reproduced"] is True
    assert report["params"]["requirement.kind"] == "drop" and report["params"]["requirement.magnitude"] == near["breaks_at"]
    errors = load_errors(folder / "attack_errors.npz")
    assert errors.fn.sum() <= math.floor(near["breaks_at"] / DT + 1e-9) and errors.fn.sum() > TOLERATED / DT
    assert not errors.dx.any() and not errors.dy.any() and not errors.dyaw.any()  # one kind only
    assert (folder / "attack").is_dir()  # the bag to hand to the planner engineers


def test_the_outputs_say_what_a_tolerated_level_is(standing):
    _, output = standing
    table = (output / "requirements.md").read_text()
    assert "an upper bound on what is safe" in table and "| standing | drop | 0-20 m | " in table
    assert all(row["caveat"].startswith("A tolerated level is") for row in rows(output))
    assert (output / "requirements-drop.png").stat().st_size > 1000
    noise = yaml.safe_load((output / "noise.yaml").read_text())
    assert noise["noise"]["model"]["version"] == 2 and noise["noise"]["v2"]["ellipse_y_radii"] == [20, 40]


def test_running_it_again_runs_no_search_and_gives_the_same_rows(standing, tmp_path, capsys):
    params, output = standing
    copy = tmp_path / "out"
    shutil.copytree(output, copy)
    before = {p.name: p.stat().st_mtime_ns for p in (copy / "searches").iterdir()}
    requirements(params, copy, "--kinds", "drop", "--bins", "20,40", "--executor", "serial", capsys=capsys)
    assert {p.name: p.stat().st_mtime_ns for p in (copy / "searches").iterdir()} == before
    assert rows(copy) == rows(output)


def test_a_process_pool_gives_the_serial_rows(standing, tmp_path, capsys):
    params, output = standing
    requirements(params, tmp_path / "pool", "--kinds", "drop", "--bins", "20,40", "--executor", "process", "--workers",
                 "2", capsys=capsys)
    assert rows(tmp_path / "pool") == rows(output)


def tolerance(accel: float) -> float:
    """The closed form: the longest miss an ego accelerating at `accel` survives (module docstring)."""
    return math.sqrt(GAP / (accel / 2 + accel**2 / (2 * DECEL)))


def test_a_campaign_file_gives_the_rows_of_each_of_its_planners(standing, tmp_path, capsys):
    """A campaign of the standing scenario with IDM as above and IDM accelerating at half the rate, which survives
    a longer miss (1.85 s: 18 frames): a row per campaign cell, each bracket holding its own planner's closed form."""
    params, _ = standing
    campaign = tmp_path / "c.yaml"
    campaign.write_text(yaml.safe_dump({"name": "c", "scenarios": [str(params)], "output": str(tmp_path / "campaign"),
                                        "planners": [{"name": "idm"}, {"name": "gentle",
                                                                       "planner_params": {"max_accel": 0.5}}]}))
    requirements(campaign, tmp_path / "out", "--kinds", "drop", "--bins", "20", "--executor", "serial", "--typical", "0",
                 capsys=capsys)
    found = {row["scenario"]: row for row in rows(tmp_path / "out")}
    assert sorted(found) == ["standing-nds_t-0-gentle", "standing-nds_t-0-idm"]
    for name, accel in (("standing-nds_t-0-idm", ACCEL), ("standing-nds_t-0-gentle", 0.5)):
        row, frames = found[name], math.floor(tolerance(accel) / DT)
        assert math.floor(row["tolerated"] / DT + 1e-9) <= frames < math.floor(row["breaks_at"] / DT + 1e-9), row
    assert not (tmp_path / "campaign").exists()  # the campaign's cells, not the campaign: nothing of it is run


CRUISING = {**FOLLOW_SPEC, "name": "cruising", "duration": 6.0, "ego": {"route": ["east"], "start_s": 100.0, "speed": 10.0},
            "agents": [FOLLOW_SPEC["agents"][1]]}  # the ego alone in its lane at its target speed, a car oncoming


def test_a_ghost_requirement_under_phantom_braking_holds_its_closed_form(tmp_path, capsys):
    """The tracker starts a track at a detection's first frame and keeps it `max_age` (1 s), so a phantom car
    shown for a single frame in the ego's path within 20 m is a standing car ahead for a second, for which IDM
    brakes at its limit (6 m/s^2, beyond the 2.94 of phantom braking): no ghost is tolerated, one frame of one
    breaks the rule. Seven halvings of [0, 10 s] end at [0.078, 0.156] s: 0 whole frames tolerated, 1 broken.
    The typical errors are judged by the row's rule, and its attack's report violates it."""
    write_ground_truth_bag(tmp_path / "bag", build_scenario(CRUISING))
    params = {"bag": str(tmp_path / "bag"), "planner": "idm", "rule": {"name": "phantom_braking"},
              "planner_params": {"target_speed": 10.0, "max_decel": 6.0}, "search": {"budget": 30}}
    (tmp_path / "cruising.yaml").write_text(yaml.safe_dump({"orchestrator": {"ros__parameters": params}}))
    requirements(tmp_path / "cruising.yaml", tmp_path / "out", "--kinds", "ghost", "--bins", "20", "--iterations", "7",
                 "--typical", "3", "--executor", "serial", capsys=capsys)
    (row,) = rows(tmp_path / "out")
    assert (row["kind"], row["bin"], row["rule"], row["unit"]) == ("ghost", "0-20 m", "phantom_braking", "s")
    assert math.floor(row["tolerated"] / DT + 1e-9) == 0 and math.floor(row["breaks_at"] / DT + 1e-9) == 1, row
    assert (row["typical_samples"], row["typical_violations"]) == (3, 0)  # no ghost at all at the tolerated level
    report = json.loads((tmp_path / "out" / row["attack"] / "report.json").read_text())
    assert report["rule"] == "phantom_braking" and report["rules"]["phantom_braking"]["violated"] is True
    assert report["reproduced"] is True and not report["rules"]["collision"]["violated"]  # braking, no contact
    errors = load_errors(tmp_path / "out" / row["attack"] / "attack_errors.npz")
    assert errors.ghost_on is not None and errors.ghost_on.sum() == 1 and not errors.fn.any()


def test_a_scenario_whose_ground_truth_breaks_the_rule_is_said_so_and_the_others_are_bracketed(tmp_path, capsys):
    """An ego rolling at 5 m/s 1 m behind a parked car collides with perfect perception: nothing is tolerated
    there, which its rows say (and the exit code, 1, as `advperc attack`'s refusal), while the closed-form
    case beside it is bracketed as alone; its position bound stays out of the noise file."""
    moving_params = standing_params(tmp_path)
    document = yaml.safe_load(moving_params.read_text())
    spec = {**STANDING, "name": "moving", "ego": {**STANDING["ego"], "speed": 5.0}}
    write_ground_truth_bag(tmp_path / "moving", build_scenario(spec))
    document["orchestrator"]["ros__parameters"]["bag"] = str(tmp_path / "moving")
    (tmp_path / "moving.yaml").write_text(yaml.safe_dump(document))
    alone = tmp_path / "alone"
    alone.mkdir()
    capsys.readouterr()
    assert main(["requirements", str(standing_params(alone)), str(tmp_path / "moving.yaml"), "--output",
                 str(tmp_path / "out"), "--kinds", "drop,position", "--bins", "20", "--executor", "serial",
                 "--typical", "2", "--quiet"]) == 1
    out = capsys.readouterr()
    assert json.loads(out.out)["ground_truth_breaks_rule"] == ["moving"]
    standing_drop, standing_position, moving_drop, moving_position = rows(tmp_path / "out")
    for row in (moving_drop, moving_position):
        assert (row["scenario"], row["tolerated"], row["breaks_at"], row["attack"]) == ("moving", 0.0, 0.0, None)
        assert "collides with perfect perception" in row["ground_truth_breaks"] and row["typical_samples"] == 0
    assert standing_drop["ground_truth_breaks"] is None and math.floor(standing_drop["tolerated"] / DT + 1e-9) == 12
    lines = out.err.strip().splitlines()
    assert len(lines) == 4 and lines[2].startswith("moving drop 0-20 m: nothing tolerated, ") and "collides" in lines[2]
    assert "perfect perception already breaks it" in (tmp_path / "out" / "requirements.md").read_text()
    noise = yaml.safe_load((tmp_path / "out" / "noise.yaml").read_text())["noise"]["v2"]
    assert noise["distance"]["standard_deviation"]["values"] == [pytest.approx(standing_position["tolerated"] / 3, rel=1e-3)]


def test_a_position_requirement_on_a_bundled_scenario_names_attacks_that_collide(repo, tmp_path, capsys):
    """The issue's command on the bundled IDM scenario, shortened (one halving, 20 rollouts a search): every
    broken bound's attack collides with position errors alone, none on cars outside its bin."""
    summary = requirements(repo / "config" / "idm_lane_following.yaml", tmp_path / "out", "--kinds", "position",
                           "--iterations", "1", "--budget", "20", "--executor", "process", "--workers", "2",
                           capsys=capsys)
    found = rows(tmp_path / "out")
    assert [row["bin"] for row in found] == ["0-20 m", "20-40 m", "40-60 m"] and summary["brackets"] == 3
    assert summary["broken"] == sum(row["breaks_at"] is not None for row in found) >= 1
    for row in found:
        if row["breaks_at"] is None:
            continue
        report = json.loads((tmp_path / "out" / row["attack"] / "report.json").read_text())
        errors = load_errors(tmp_path / "out" / row["attack"] / "attack_errors.npz")
        assert report["collision"] is True and not errors.fn.any()
        assert np.hypot(errors.dx, errors.dy).max() <= row["breaks_at"] * (1 + 1e-9)


def test_a_run_killed_midway_resumes_to_the_uninterrupted_rows(standing, tmp_path, capsys):
    """SIGKILL once two searches are in place (a third may be half-written: its staging folder and checkpoint);
    the same command again gives the rows of a run never interrupted."""
    params, output = standing
    command = [sys.executable, "-m", "advperc_ros.cli", "requirements", str(params), "--output", str(tmp_path / "out"),
               "--kinds", "drop", "--bins", "20,40", "--executor", "serial", "--quiet"]
    run = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    deadline = time.monotonic() + 300
    while run.poll() is None and time.monotonic() < deadline:
        if len([p for p in (tmp_path / "out" / "searches").glob("*") if not p.name.startswith(".")]) >= 2:
            break
        time.sleep(0.2)
    os.killpg(run.pid, signal.SIGKILL)
    run.wait()
    assert not (tmp_path / "out" / "requirements.json").exists() or rows(tmp_path / "out") != rows(output)
    requirements(params, tmp_path / "out", "--kinds", "drop", "--bins", "20,40", "--executor", "serial", capsys=capsys)
    assert rows(tmp_path / "out") == rows(output)


def test_typical_errors_that_break_the_rule_within_a_tolerated_level_are_called_out():
    """The search tolerated 10 s of ghosts 20-40 m away, yet 3 of 10 typical samples within that level break the
    rule (ghosts coming towards the ego, which the search's moves never propose): the row must not read as safe."""
    from advperc_ros.requirements import Bracket, markdown

    row = Bracket("rec", "ghost", "s", 20.0, 40.0, 10.0, None, None, "phantom_braking", 45, 1, 10, 3)
    assert "3 of 10 break it (the search missed them: not tolerated)" in markdown([row])
    assert row.line().endswith("not broken; yet 3 of 10 typical errors within it break the rule")
    fine = Bracket("rec", "ghost", "s", 20.0, 40.0, 10.0, None, None, "phantom_braking", 45, 1, 10, 0)
    assert "| 0 of 10 break it |" in markdown([fine]) and fine.line().endswith("not broken")


@pytest.mark.parametrize("scenarios", [2, 22])
def test_the_plot_draws_a_few_scenarios_as_bars_and_many_as_marks(scenarios, tmp_path, monkeypatch):
    """A run across 22 recordings drew 66 bars with their labels on top of one another: past a handful of
    scenarios each bracket is a mark. Either way, one of them whose ground truth breaks the rule is drawn."""
    from advperc_ros.requirements import Bracket
    from advperc_ros.results import plots

    drawn: list[str] = []
    monkeypatch.setattr(plots, "_requirement_bars", lambda ax, *rest: drawn.append("bars"))
    monkeypatch.setattr(plots, "_requirement_marks", lambda ax, *rest: drawn.append("marks"))
    rows = [Bracket(f"s{i}", "drop", "s", near, near + 20.0, t, b, None, "collision", 1, 1, ground_truth_breaks=gt)
            for i in range(scenarios) for near in (0.0, 20.0)
            for t, b, gt in [(10.0, None, None) if i % 3 else (0.0, 0.0, "collides") if i == 0 else (1.25, 1.5625, None)]]
    plots.requirements(tmp_path / "stubbed.png", rows)
    assert drawn == ["bars" if scenarios <= plots.BAR_SCENARIOS else "marks"]
    monkeypatch.undo()
    plots.requirements(tmp_path / "drop.png", rows)
    assert (tmp_path / "drop.png").stat().st_size > 1000
