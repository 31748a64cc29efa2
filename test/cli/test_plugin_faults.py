"""A plug-in planner's faults, wherever they happen (import, construction, reset, plan), end in one line
that names the plug-in or the planner and the phase: exit 2 before any rollout when it cannot be built,
exit 1 (nothing to attack) when even the ground-truth rollout cannot finish. Never a traceback, never a
silent pass."""

import pytest

from test_cli import write_params

from advperc_ros.cli import main


@pytest.mark.parametrize("planner, code, says", [
    ("planner_failing_at_import:Anything", 2,
     "planner 'planner_failing_at_import:Anything': importing planner_failing_at_import raised RuntimeError: CUDA not found"),
    ("faulty_planners:FailsToConstruct", 2,
     "planner 'faulty_planners:FailsToConstruct': constructing it raised RuntimeError: no licence server"),
    ("faulty_planners:FailsToReset", 1, "ground-truth rollout is inconclusive: frame 0: planner's reset() raised KeyError"),
    ("faulty_planners:ReturnsNothing", 1, "frame 0: planner returned NoneType, not a Trajectory"),
    ("faulty_planners:Exits", 1, "frame 0: planner raised SystemExit: 3"),
])
def test_a_plug_in_s_fault_is_one_line_naming_it_and_the_phase(repo, tmp_path, capsys, planner, code, says):
    params = write_params(tmp_path / "p.yaml", repo, planner=planner)
    capsys.readouterr()
    assert main(["attack", str(params), "--output", str(tmp_path / "out"), "--quiet"]) == code
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and says in err and "Traceback" not in err, err
    assert sorted(path.name for path in tmp_path.iterdir()) == ["p.yaml"]  # nothing written, no checkpoint left
