"""Fuzzing a plug-in planner's faults: any exception, a wrong return value or sys.exit with any code,
in construction, reset or plan, at its first call or any later one (a later rollout, a later frame).
The attack ends in one of its documented ways, each said in one line with its exit code: 2 before any
rollout (naming the plug-in and that constructing it failed), 1 when the ground-truth rollout cannot
finish (naming the frame and the fault), 4 when most of the search's rollouts were inconclusive, or 0
with a report, the faulty rollouts counted inconclusive. Never a traceback, never a silent exit, and
nothing left behind on a failure."""

import json

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from advperc_ros.cli import main
from conftest import REPO
from faulty_planners import FAULTS, WRONG_PLANS
from test_cli import write_params

# a handful of whole (short) attacks: each example runs the ground truth and a few rollouts
FUZZ = settings(max_examples=8, deadline=None, derandomize=True, suppress_health_check=list(HealthCheck))
PLANNER = "faulty_planners:FaultAt"


@given(phase=st.integers(0, 2), kind=st.integers(0, 2), index=st.integers(0, max(len(FAULTS), len(WRONG_PLANS), 256)),
       after=st.sampled_from([0, 0, 1, 3, 40, 400]))
@FUZZ
def test_any_fault_of_a_plug_in_ends_in_one_documented_way(phase, kind, index, after, tmp_path_factory, capsys):
    folder = tmp_path_factory.mktemp("fault")
    fault = {"fault_phase": phase, "fault_kind": kind, "fault_index": index, "fault_after": after}
    params = write_params(folder / "p.yaml", REPO, planner=PLANNER, planner_params={"target_speed": 14.0, **fault},
                          **{"search.budget": 12})
    capsys.readouterr()
    code = main(["attack", str(params), "--output", str(folder / "out"), "--quiet"])
    out, err = capsys.readouterr()
    lines = err.strip().splitlines()
    assert "Traceback" not in err, err
    if code == 0:
        report = json.loads((folder / "out" / "report.json").read_text())
        assert json.loads(out)["rollouts"] == report["rollouts"] and len(lines) == 1, (out, err)
        return
    assert len(lines) == 1 and lines[0].startswith("advperc:"), err
    assert sorted(p.name for p in folder.iterdir()) == ["p.yaml"], "a failed attack left something behind"
    if code == 2:
        assert phase == 0 and after == 0 and f"planner '{PLANNER}': constructing it raised" in err, err
    elif code == 1:
        assert "ground-truth rollout is inconclusive" in err and "frame" in err, err
    else:
        assert code == 4 and "inconclusive" in err, err
